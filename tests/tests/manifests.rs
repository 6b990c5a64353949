//! Itemised stages are stored once: every item is an object of its own, the final artifact is
//! a manifest of them (the same for any shard count), the record lists them as its parts;
//! consumers assemble or stream it; gc, verify, status and make follow the parts.

use osms_core::decode;
use osms_make::{Manifest, State, StoreObjects, assemble};
use osms_tests::Project;
use osms_tests::artifacts::{Numbers, Total};
use osms_tests::project::{hashes, outcomes};

#[test]
fn an_itemised_stage_is_a_manifest_of_its_items_and_nothing_more() {
    let p = Project::engine();
    let report = p.make(None, &[0], 2);
    let h = hashes(&report);
    let store = p.open_store();
    let (records, _) = store.records().expect("records");
    let numbers = records
        .iter()
        .find(|r| r.shard.is_none() && r.stage == "numbers" && r.seed == Some(0))
        .expect("numbers@0 record");
    assert_eq!(numbers.content_hash, h["numbers@0"]);
    assert_eq!(numbers.parts.len(), 12, "an object per item: {numbers:?}");

    let bytes = store.get(&numbers.content_hash).expect("manifest");
    let manifest: Manifest<Numbers> = decode(&bytes).expect("a manifest");
    assert!(manifest.head.rows.is_empty(), "the head holds no rows");
    assert_eq!(manifest.items, numbers.parts);
    let distinct: std::collections::BTreeSet<_> = manifest.items.iter().collect();
    assert_eq!(distinct.len(), 12);

    // Assembled, it is the whole artifact; `sum` streamed the same rows shard by shard.
    let whole: Numbers = assemble(&bytes, &StoreObjects(&store)).expect("assemble");
    assert_eq!(whole.rows.len(), 12);
    let total: Total = decode(&store.get(&h["total@0"]).expect("total")).expect("total");
    let expected: f64 = whole.rows.iter().flatten().sum();
    assert_eq!(total.count, 48);
    assert_eq!(total.sum, expected);
}

#[test]
fn gc_keeps_the_items_of_a_complete_stage_and_status_sees_a_missing_one() {
    let p = Project::engine();
    let first = p.make(None, &[0], 2);
    let store = p.open_store();
    let plan = p.plan(None).expect("plan");
    let statuses = osms_make::status(&plan, &store, &[], &[0]).expect("status");
    let keep = statuses.iter().filter_map(|s| s.key).collect();
    let report = store.gc(&keep, &keep, false).expect("gc");
    // Only the shard lists of the complete stages go (one per shard: 3 + 2 + 1); every item
    // stays, as a part of its stage's record.
    assert_eq!(report.records_removed.len(), 6, "{report:?}");
    assert_eq!(report.objects_removed.len(), 6, "{report:?}");
    let (kept, _) = store.records().expect("records");
    assert!(kept.iter().all(|r| r.shard.is_none()));
    for r in &kept {
        for part in &r.parts {
            assert!(
                !report.objects_removed.contains(part),
                "{} lost an item",
                r.stage
            );
            store.get(part).expect("item kept");
        }
    }
    assert!(store.verify().expect("verify").problems.is_empty());
    let again = p.make(None, &[0], 2);
    assert!(
        outcomes(&again).values().all(|o| *o == "cached"),
        "{again:?}"
    );

    // An item gone: the stage is missing (naming the item) and is rebuilt to the same bytes.
    let (records, _) = store.records().expect("records");
    let numbers = records
        .iter()
        .find(|r| r.shard.is_none() && r.stage == "numbers" && r.seed == Some(0))
        .expect("numbers@0");
    let gone = numbers.parts[5];
    std::fs::remove_file(store.object_path(&gone)).expect("remove item");
    let store = p.open_store();
    let statuses = osms_make::status(&plan, &store, &[], &[0]).expect("status");
    let s = statuses
        .iter()
        .find(|s| s.instance == "numbers@0")
        .expect("numbers@0");
    assert_eq!(s.state, State::Missing);
    assert_eq!(
        osms_make::describe(&s.reasons),
        format!("object {} is missing", gone.short())
    );
    let problems = store.verify().expect("verify").problems;
    assert_eq!(problems.len(), 1, "{problems:?}");
    let rebuilt = p.make(None, &[0], 1);
    let o = outcomes(&rebuilt);
    assert_eq!(o["numbers@0"], "built");
    assert_eq!(o["total@0"], "cut off");
    assert_eq!(hashes(&rebuilt), hashes(&first));
    p.open_store().get(&gone).expect("the item is back");
}

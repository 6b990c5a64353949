//! The stage kinds a program knows, by name.

use std::collections::BTreeMap;
use std::sync::Arc;

use super::author::{ItemStage, Stage};
use super::erased::{DynKind, Itemised, KindInfo, Plain};

/// The stage kinds a program knows, by name.
#[derive(Default, Clone)]
pub struct Registry {
    kinds: BTreeMap<&'static str, Arc<dyn DynKind>>,
}

impl Registry {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn register<S: Stage>(&mut self, stage: S) -> &mut Self {
        self.insert(S::KIND, Arc::new(Plain(stage)))
    }

    pub fn register_itemised<S: ItemStage>(&mut self, stage: S) -> &mut Self {
        self.insert(S::KIND, Arc::new(Itemised(stage)))
    }

    fn insert(&mut self, name: &'static str, kind: Arc<dyn DynKind>) -> &mut Self {
        let previous = self.kinds.insert(name, kind);
        assert!(
            previous.is_none(),
            "stage kind `{name}` is registered twice"
        );
        self
    }

    pub fn get(&self, name: &str) -> Option<&Arc<dyn DynKind>> {
        self.kinds.get(name)
    }

    pub fn names(&self) -> Vec<&'static str> {
        self.kinds.keys().copied().collect()
    }

    pub fn infos(&self) -> Vec<KindInfo> {
        self.kinds.values().map(|k| k.info()).collect()
    }
}

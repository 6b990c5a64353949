//! The OSW motion manifold as an artifact: the trained conditional VAE with its learning curve.

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::Summarize;

use crate::cvae::{CurvePoint, Cvae};

impl Artifact for Cvae {
    const TYPE_TAG: &'static str = "method.manifold";
    const SCHEMA_VERSION: u16 = 1;
}

impl Summarize for Cvae {
    fn summary(&self) -> serde_json::Value {
        let last = self.curve.last();
        serde_json::json!({
            "conditional": self.params.conditional,
            "latent": self.params.latent,
            "h_os": self.h_os,
            "omega_bar_len": self.omega_mean.len(),
            "windows_train": self.windows_train,
            "windows_heldout": self.windows_heldout,
            "epochs": self.curve.len(),
            "train_reconstruction": last.map(|c| c.reconstruction),
            "heldout_reconstruction": last.map(|c| c.heldout_reconstruction),
            "heldout_prior_reconstruction": last.map(|c| c.heldout_prior_reconstruction),
            "kl": last.map(|c| c.kl),
        })
    }

    fn text(&self) -> Option<String> {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{} manifold: latent {}, ζ = {} steps × {} channels, trained on {} windows, {} held out",
            if self.params.conditional {
                "conditional"
            } else {
                "unconditional"
            },
            self.params.latent,
            self.h_os,
            self.channels,
            self.windows_train,
            self.windows_heldout
        );
        let _ = writeln!(
            s,
            "errors are ‖·‖²_{{W_a}} per element: 1.0 = predicting each channel's mean\n"
        );
        let mut t = Table::new(
            "manifold_curve",
            "Manifold learning curve",
            vec![
                Column::new("train rec", Unit::Number(4)),
                Column::new("smooth", Unit::Number(4)),
                Column::new("KL", Unit::Number(3)),
                Column::new("held-out rec (encoder mean)", Unit::Number(4)),
                Column::new("held-out rec (prior mean)", Unit::Number(4)),
            ],
        );
        let step = self.curve.len().div_ceil(10).max(1);
        let mut shown: Vec<&CurvePoint> = self.curve.iter().step_by(step).collect();
        if let Some(last) = self.curve.last()
            && shown.last().is_none_or(|s| s.epoch != last.epoch)
        {
            shown.push(last);
        }
        for c in shown {
            t.push(
                c.epoch.to_string(),
                [
                    c.reconstruction,
                    c.smoothness,
                    c.kl,
                    c.heldout_reconstruction,
                    c.heldout_prior_reconstruction,
                ]
                .map(|v| Cell::one(f64::from(v)))
                .to_vec(),
            );
        }
        s.push_str(&t.markdown_with(Layout::numbered("epoch")));
        Some(s)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from(
            "epoch,train_reconstruction,smoothness,kl,heldout_reconstruction,heldout_prior_reconstruction\n",
        );
        for c in &self.curve {
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{}",
                c.epoch,
                c.reconstruction,
                c.smoothness,
                c.kl,
                c.heldout_reconstruction,
                c.heldout_prior_reconstruction
            );
        }
        vec![("manifold_curve.csv".into(), csv.into_bytes())]
    }
}

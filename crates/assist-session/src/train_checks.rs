//! The checks of a training configuration that need no dataset: each bad value is an
//! error naming its option and what was expected.

use crate::train_config::{MAX_BATCH_SAMPLES, MIN_BATCH_SAMPLES, TrainConfig};
use crate::{SessionError, request};

impl TrainConfig {
    /// Checks the configuration without reading the dataset.
    pub fn validate(&self) -> crate::Result<()> {
        let c = self;
        if c.data.as_os_str().is_empty() {
            return Err(request("data", "expected a dataset path".into()));
        }
        if c.out.as_os_str().is_empty() {
            return Err(request("out", "expected a scene path to write".into()));
        }
        if c.out.exists() && !c.force && !c.resume {
            return Err(SessionError::OutExists(c.out.clone()));
        }
        if !(MIN_BATCH_SAMPLES..=MAX_BATCH_SAMPLES).contains(&c.batch_samples) {
            return Err(request(
                "batch_samples",
                format!(
                    "expected {MIN_BATCH_SAMPLES} to {MAX_BATCH_SAMPLES}, got {}",
                    c.batch_samples
                ),
            ));
        }
        let lrs = [("lr_start", Some(c.lr_start)), ("lr_end", c.lr_end)];
        for (what, lr) in lrs.into_iter().filter_map(|(w, lr)| Some((w, lr?))) {
            if !(lr.is_finite() && lr > 0.0 && lr <= 1.0) {
                return Err(request(
                    what,
                    format!("expected a learning rate above 0 and at most 1, got {lr}"),
                ));
            }
        }
        if let Some(t) = c.max_time
            && !(t.is_finite() && t > 0.0)
        {
            return Err(request(
                "max_time",
                format!("expected a positive number of seconds, got {t}"),
            ));
        }
        if c.no_objects && c.masks.is_some() {
            return Err(request(
                "no_objects",
                "--no-objects trains the background alone; --masks gives objects: choose one"
                    .into(),
            ));
        }
        if c.no_objects && c.boxes.is_some() {
            return Err(request(
                "no_objects",
                "--no-objects trains the background alone; --boxes gives objects: choose one"
                    .into(),
            ));
        }
        if c.eval_every.is_some() && c.eval_views == 0 {
            return Err(request(
                "eval_views",
                "expected at least 1 view to evaluate every eval_every iterations".into(),
            ));
        }
        if !(0.0..=1.0).contains(&c.object_rays) {
            return Err(request(
                "object_rays",
                format!("expected a fraction between 0 and 1, got {}", c.object_rays),
            ));
        }
        if !(0.25..=8.0).contains(&c.step_scale) {
            return Err(request(
                "step_scale",
                format!(
                    "expected a step factor between 0.25 and 8 (1 = as rendered), got {}",
                    c.step_scale
                ),
            ));
        }
        if let Some(n) = c.proposal
            && n > 1024
        {
            return Err(request(
                "proposal",
                format!("expected at most 1024 samples per ray (0 = off), got {n}"),
            ));
        }
        if let Some(t) = c.prune_eps
            && !(0.0..1.0).contains(&t)
        {
            return Err(request(
                "prune_eps",
                format!("expected a transmittance of at least 0 and below 1 (0 = off), got {t}"),
            ));
        }
        if let Some(d) = c.grid_decay
            && !(d.is_finite() && (0.0..=1.0).contains(&d))
        {
            return Err(request(
                "grid_decay",
                format!("expected a decay of at least 0 and at most 1 (0 = off), got {d}"),
            ));
        }
        if let Some(assist_train::GridResolution::Cells(r)) = c.grid_resolution
            && !(16..=65_536).contains(&r)
        {
            return Err(request(
                "grid_resolution",
                format!("expected 16 to 65536 cells or auto, got {r}"),
            ));
        }
        if let Some(e) = c.error_rays
            && !(e.is_finite() && (0.0..=0.9).contains(&e))
        {
            return Err(request(
                "error_rays",
                format!(
                    "expected a share of the rays of at least 0 and at most 0.9 (0 = off), got {e}"
                ),
            ));
        }
        if !(0.0..=1.0).contains(&c.hidden_stop) {
            return Err(request(
                "hidden_stop",
                format!(
                    "expected a transmittance between 0 and 1 (0 = off), got {}",
                    c.hidden_stop
                ),
            ));
        }
        for (name, v) in c.lambdas.iter() {
            if !(v.is_finite() && v >= 0.0) {
                return Err(request(
                    &crate::train_config::lambda_key(name),
                    format!("expected a finite weight of 0 or more (0 = off), got {v}"),
                ));
            }
        }
        if c.resume && c.boxes.is_some() {
            return Err(request(
                "boxes",
                "cannot change the boxes of a scene being resumed (train anew instead)".into(),
            ));
        }
        if !(1..=64).contains(&c.downscale) {
            return Err(request(
                "downscale",
                format!("expected 1 to 64, got {}", c.downscale),
            ));
        }
        Ok(())
    }
}

//! A seed ensemble as a controller runs it (docs/embedding.md "Ensembles and intervals"):
//! the members' mean prediction, how far the members are from it (their spread), and a
//! calibrated interval, a radius proportional to the spread. `iastgcn confidence`
//! measures the scale on the validation session and writes it with the members into an
//! ensemble file ([`EnsembleFile`], docs/results.md "Confidence"); the twin's loop, the
//! C ABI and the Python package all run this one type.

use std::borrow::BorrowMut;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::SensorPredictor;
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::model::{Checkpoint, ModelError, Predictor, Residual};

/// The radius of an interval for one quantity (position µm, or attitude mdeg): `scale`
/// times the members' spread ([`spread`]) plus `constant`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Radius {
    /// Radius per unit of spread.
    #[serde(default)]
    pub scale: f64,
    /// Radius whatever the spread, in the quantity's unit.
    #[serde(default)]
    pub constant: f64,
}

impl Radius {
    /// The radius of a prediction whose members' spread is `spread`.
    pub fn of(&self, spread: f64) -> f64 {
        self.scale * spread + self.constant
    }
}

/// A calibrated interval: its level and the radius of each quantity. `iastgcn
/// confidence` calibrates both kinds (spread-scaled, constant) on the validation session
/// and keeps, per quantity, the one narrower there.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IntervalCalibration {
    /// The share of the calibration session's predictions the interval covered (0.9 for
    /// a 90 % interval).
    pub level: f64,
    /// The position radius, µm.
    pub position: Radius,
    /// The attitude radius, mdeg.
    pub attitude: Radius,
}

impl IntervalCalibration {
    /// Refuses a level outside (0, 1) and radii with a negative or non-finite term or
    /// none at all.
    pub fn validate(&self) -> Result<(), ModelError> {
        if !(self.level > 0.0 && self.level < 1.0) {
            return Err(ModelError::Config(format!(
                "interval.level: a share between 0 and 1 (0.9 for a 90 % interval), got {}",
                self.level
            )));
        }
        for (name, r) in [("position", self.position), ("attitude", self.attitude)] {
            let terms = [r.scale, r.constant];
            if !terms.iter().all(|t| t.is_finite() && *t >= 0.0) || terms == [0.0, 0.0] {
                return Err(ModelError::Config(format!(
                    "interval.{name}: scale and constant are numbers ≥ 0, not both 0; got \
                     {} and {}",
                    r.scale, r.constant
                )));
            }
        }
        Ok(())
    }
}

/// The interval of one prediction: the true residual lies within `position_um` of the
/// predicted position (a ball) and within `attitude_mdeg` of the predicted attitude
/// across the tool axis with the calibrated share `level`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interval {
    /// The share of the calibration session's predictions an interval like it covered.
    pub level: f64,
    /// Position radius, µm.
    pub position_um: f64,
    /// Attitude radius, mdeg.
    pub attitude_mdeg: f64,
}

/// The members' root-mean-square distance from their mean: position (the 3-D distance,
/// µm) and attitude (the 3-D rotation-vector difference, mdeg). 0 for one member.
pub fn spread(predictions: &[Residual]) -> [f64; 2] {
    let n = predictions.len().max(1) as f64;
    let mean: Residual = std::array::from_fn(|k| predictions.iter().map(|p| p[k]).sum::<f64>() / n);
    let (mut pos, mut att) = (0.0, 0.0);
    for p in predictions {
        pos += (0..3).map(|k| (p[k] - mean[k]).powi(2)).sum::<f64>() / n;
        att += (3..6).map(|k| (p[k] - mean[k]).powi(2)).sum::<f64>() / n;
    }
    [pos.sqrt(), att.sqrt()]
}

/// The seeds of one model fed with the same sensor values: the prediction is their mean,
/// the interval (when calibrated) a radius from their spread. No call after
/// construction allocates.
pub struct Ensemble<P: BorrowMut<Predictor> = Predictor> {
    members: Vec<SensorPredictor<P>>,
    /// Each member's last prediction (µm, mdeg).
    last: Vec<Residual>,
    /// Whether `last` holds a prediction of the current run.
    predicted: bool,
    interval: Option<IntervalCalibration>,
}

impl<P: BorrowMut<Predictor>> Ensemble<P> {
    /// The ensemble of `members` (at least one; the same shapes and look-ahead), with
    /// the calibrated `interval` scale or none.
    pub fn new(
        members: Vec<SensorPredictor<P>>,
        interval: Option<IntervalCalibration>,
    ) -> Result<Ensemble<P>, ModelError> {
        let Some(first) = members.first() else {
            return Err(ModelError::Config(
                "an ensemble needs at least one member".into(),
            ));
        };
        let shape = |m: &SensorPredictor<P>| {
            let c = m.predictor().config();
            (c.nodes, c.features, c.window)
        };
        let (want, ahead) = (shape(first), first.predictor().config().look_ahead);
        for (i, m) in members.iter().enumerate() {
            if shape(m) != want {
                return Err(ModelError::Config(format!(
                    "ensemble member {}: shape (nodes, features, window) {:?}, the first \
                     member's is {want:?}",
                    i + 1,
                    shape(m)
                )));
            }
            if m.predictor().config().look_ahead != ahead {
                return Err(ModelError::Config(format!(
                    "ensemble member {}: an ensemble's members must predict the same tick \
                     (look_ahead {} against the first member's {ahead})",
                    i + 1,
                    m.predictor().config().look_ahead
                )));
            }
        }
        if let Some(scale) = &interval {
            scale.validate()?;
        }
        Ok(Ensemble {
            last: vec![[0.0; 6]; members.len()],
            members,
            predicted: false,
            interval,
        })
    }

    /// The members.
    pub fn members(&self) -> &[SensorPredictor<P>] {
        &self.members
    }

    /// The members, to change how they run ([`Predictor::set_threads`]).
    pub fn members_mut(&mut self) -> &mut [SensorPredictor<P>] {
        &mut self.members
    }

    /// The first member's predictor (every member has its shapes).
    pub fn first(&self) -> &Predictor {
        self.members[0].predictor()
    }

    /// The interval's calibration, if any.
    pub fn interval_calibration(&self) -> Option<IntervalCalibration> {
        self.interval
    }

    /// Pushes one tick of raw sensor values into every member
    /// ([`SensorPredictor::push_values`]); true once each has a window.
    pub fn push_values(&mut self, values: &[Option<f64>]) -> Result<bool, ModelError> {
        let mut full = true;
        for m in self.members.iter_mut() {
            full &= m.push_values(values)?;
        }
        Ok(full)
    }

    /// As [`Ensemble::push_values`], NaN for "no sample this tick".
    pub fn push(&mut self, frame: &[f64]) -> Result<bool, ModelError> {
        let mut full = true;
        for m in self.members.iter_mut() {
            full &= m.push(frame)?;
        }
        Ok(full)
    }

    /// The members' mean prediction for the window ending at the last pushed tick;
    /// `None` until every member has a window.
    pub fn predict_latest(&mut self) -> Result<Option<Residual>, ModelError> {
        let mut r = [0.0; 6];
        let share = 1.0 / self.members.len() as f64;
        for (member, last) in self.members.iter_mut().zip(self.last.iter_mut()) {
            let Some(one) = member.predict_latest()? else {
                return Ok(None);
            };
            for ((sum, v), l) in r.iter_mut().zip(one).zip(last.iter_mut()) {
                *sum += share * v;
                *l = v;
            }
        }
        self.predicted = true;
        Ok(Some(r))
    }

    /// The members' spread ([`spread`]) at the last prediction; `None` before one.
    pub fn spread(&self) -> Option<[f64; 2]> {
        self.predicted.then(|| spread(&self.last))
    }

    /// The calibrated interval of the last prediction; `None` before one or without a
    /// calibration.
    pub fn interval(&self) -> Option<Interval> {
        let [pos, att] = self.spread()?;
        self.interval.map(|c| Interval {
            level: c.level,
            position_um: c.position.of(pos),
            attitude_mdeg: c.attitude.of(att),
        })
    }

    /// Forgets the pushed ticks and the last prediction (a new run).
    pub fn reset(&mut self) {
        for m in self.members.iter_mut() {
            m.reset();
        }
        self.predicted = false;
    }

    /// The control period, s.
    pub fn dt(&self) -> f64 {
        self.members[0].dt()
    }
}

/// An ensemble file (TOML): the members' checkpoints and the calibrated interval, as
/// `iastgcn confidence` writes one per model (docs/embedding.md "Ensembles and
/// intervals").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnsembleFile {
    /// The members' checkpoints; a relative path is relative to the file's folder.
    pub members: Vec<PathBuf>,
    /// Where and how the interval was calibrated (for people; not read).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub calibrated_on: String,
    /// The calibrated interval; without it the ensemble predicts without an interval.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub interval: Option<IntervalCalibration>,
}

impl EnsembleFile {
    /// Reads and checks the file at `path`; errors name it.
    pub fn read(path: &Path) -> Result<EnsembleFile> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let file: EnsembleFile = toml::from_str(&text)
            .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
        if file.members.is_empty() {
            return Err(Error::Invalid(format!(
                "{}: members: an ensemble needs at least one checkpoint",
                path.display()
            )));
        }
        if let Some(s) = &file.interval {
            s.validate()
                .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
        }
        Ok(file)
    }

    /// The file's text; errors name it `name`.
    pub fn to_toml(&self, name: &str) -> Result<String> {
        toml::to_string(self).map_err(|e| Error::Invalid(format!("{name}: {e}")))
    }

    /// Writes the file to `path` atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = self.to_toml(&path.display().to_string())?;
        crate::atomic::write(path, text.as_bytes()).map_err(|e| Error::io(path, e))
    }

    /// The members' paths, relative ones taken from the folder of the file at `path`.
    pub fn member_paths(&self, path: &Path) -> Vec<PathBuf> {
        let folder = path.parent().unwrap_or(Path::new(""));
        self.members.iter().map(|m| folder.join(m)).collect()
    }
}

impl Ensemble {
    /// Loads the ensemble file at `path` for sensor values every `dt` s: each member on
    /// `device` ([`Predictor::on`]), or natively without one. The members must read the
    /// same graph.
    pub fn load(path: &Path, dt: f64, device: Option<&Device>) -> Result<(Ensemble, Checkpoint)> {
        let file = EnsembleFile::read(path)?;
        let mut members = Vec::with_capacity(file.members.len());
        let mut first: Option<Checkpoint> = None;
        for member in file.member_paths(path) {
            let context = || format!("{}: member {}", path.display(), member.display());
            let checkpoint =
                Checkpoint::load(&member).map_err(|e| Error::from(e).context(context()))?;
            if let Some(f) = &first {
                if f.graph.nodes != checkpoint.graph.nodes {
                    return Err(Error::Invalid(format!(
                        "{}: it reads the graph nodes {:?}, the first member {:?}",
                        context(),
                        checkpoint.graph.nodes,
                        f.graph.nodes
                    )));
                }
            }
            let predictor = match device {
                Some(d) => Predictor::on(d, &checkpoint, 8),
                None => Predictor::native(&checkpoint),
            }
            .map_err(|e| Error::from(e).context(context()))?;
            members.push(
                SensorPredictor::new(predictor, dt)
                    .map_err(|e| Error::from(e).context(context()))?,
            );
            first.get_or_insert(checkpoint);
        }
        let ensemble = Ensemble::new(members, file.interval)
            .map_err(|e| Error::from(e).context(path.display().to_string()))?;
        let checkpoint =
            first.ok_or_else(|| Error::Invalid(format!("{}: members: none", path.display())))?;
        Ok((ensemble, checkpoint))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spread_is_the_members_rms_distance_from_their_mean() {
        assert_eq!(spread(&[[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]]), [0.0, 0.0]);
        // Two members 2·(3, 4, 0) µm and 2·(0, 0, 1) mdeg apart: each is half that from
        // the mean.
        let a = [0.0, 0.0, 0.0, 1.0, 1.0, 0.0];
        let b = [6.0, 8.0, 0.0, 1.0, 1.0, 2.0];
        let [pos, att] = spread(&[a, b]);
        assert!((pos - 5.0).abs() < 1e-12 && (att - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ensemble_files_are_checked_and_name_themselves() {
        let dir = std::env::temp_dir().join(format!("iastgcn-ensemble-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("e.ensemble.toml");
        let read = |text: &str| {
            std::fs::write(&path, text).unwrap();
            EnsembleFile::read(&path).map_err(|e| e.to_string())
        };
        let good = read("members = [\"a.safetensors\", \"/x/b.safetensors\"]\n\n[interval]\nlevel = 0.9\nposition = { scale = 2.0 }\nattitude = { constant = 3.0 }\n").unwrap();
        assert_eq!(
            good.member_paths(&path),
            vec![dir.join("a.safetensors"), PathBuf::from("/x/b.safetensors")]
        );
        let c = good.interval.unwrap();
        assert_eq!((c.position.of(10.0), c.attitude.of(10.0)), (20.0, 3.0));
        assert!(read("members = [\"a.safetensors\"]\n")
            .unwrap()
            .interval
            .is_none());
        for (text, says) in [
            ("members = []\n", "members"),
            ("members = [\"a\"]\nseeds = 3\n", "seeds"),
            ("members = [\"a\"]\n[interval]\nlevel = 1.5\nposition = { scale = 2.0 }\nattitude = { scale = 3.0 }\n", "level"),
            ("members = [\"a\"]\n[interval]\nlevel = 0.9\nposition = { scale = -2.0 }\nattitude = { scale = 3.0 }\n", "interval.position"),
            ("members = [\"a\"]\n[interval]\nlevel = 0.9\nposition = { scale = 2.0 }\nattitude = {}\n", "interval.attitude"),
        ] {
            let e = read(text).unwrap_err();
            assert!(e.contains("e.ensemble.toml") && e.contains(says), "{text}: {e}");
        }
        // What `write` writes, `read` reads back.
        good.write(&path).unwrap();
        assert_eq!(EnsembleFile::read(&path).unwrap(), good);
        std::fs::remove_dir_all(&dir).ok();
    }
}

//! A new measurement campaign (docs/arms.md "A new campaign"): the tracker stands
//! elsewhere and the probe was mounted again, the arm is the one calibrated before. How
//! well do a few poses of the new campaign serve, re-registering the calibrated
//! kinematics, against a full calibration on the same few poses and against registering
//! the nominal kinematics on them?

use super::report::seeds::Spread;
use crate::calibrate::arm::{
    arm_orientation_errors, arm_position_errors, calibrate_arm, reregister, ArmCalibration,
    ArmCalibrationConfig, ArmCalibrationError,
};
use crate::robot::arm::{Arm, ArmPose};
use crate::stats::Summary;

/// How the few poses are used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CampaignMethod {
    /// The calibrated kinematics, tracker and tool fitted again.
    Reregistered,
    /// Every parameter the description allows, fitted on the few poses from nominal.
    FullCalibration,
    /// The nominal kinematics, tracker and tool fitted.
    NominalRegistered,
}

impl CampaignMethod {
    /// The three, in table order.
    pub const ALL: [CampaignMethod; 3] = [
        CampaignMethod::Reregistered,
        CampaignMethod::FullCalibration,
        CampaignMethod::NominalRegistered,
    ];

    /// The row's name.
    pub fn label(self) -> &'static str {
        match self {
            CampaignMethod::Reregistered => "calibrated kinematics, re-registered",
            CampaignMethod::FullCalibration => "full calibration on these poses",
            CampaignMethod::NominalRegistered => "nominal kinematics, registered",
        }
    }
}

/// One method over the blocks: each block's mean error on the poses it did not fit.
#[derive(Clone, Debug)]
pub struct CampaignRow {
    /// The method.
    pub method: CampaignMethod,
    /// Per block, the mean position error (µm) on the scored poses; `None` where the fit
    /// was refused (too few poses for what it identifies).
    pub position_um: Vec<Option<f64>>,
    /// Per block, the mean orientation error (mdeg), where the poses have orientation.
    pub orientation_mdeg: Vec<Option<f64>>,
    /// Why a block's fit was refused, the first time.
    pub refused: Option<String>,
}

/// The study: `fit` poses a block, `blocks` disjoint blocks from the start of the file.
#[derive(Clone, Debug)]
pub struct CampaignStudy {
    /// Poses each fit used.
    pub fit: usize,
    /// Poses each fit was scored on (all the others).
    pub scored: usize,
    /// One row per method.
    pub rows: Vec<CampaignRow>,
    /// The re-registration on the first block (what `register --fit` writes).
    pub first: ArmCalibration,
}

/// Fits each of [`CampaignMethod::ALL`] on `blocks` disjoint blocks of `fit` poses
/// (poses `k·fit … (k+1)·fit − 1`) and scores each on all the other poses. `nominal` is
/// the description `calibrated` was calibrated from.
pub fn campaign_study(
    calibrated: &Arm,
    nominal: &Arm,
    poses: &[ArmPose],
    fit: usize,
    blocks: usize,
) -> Result<CampaignStudy, ArmCalibrationError> {
    let c = ArmCalibrationConfig::default();
    let blocks = blocks.max(1);
    let mut rows: Vec<CampaignRow> = CampaignMethod::ALL
        .iter()
        .map(|&method| CampaignRow {
            method,
            position_um: Vec::new(),
            orientation_mdeg: Vec::new(),
            refused: None,
        })
        .collect();
    // The first block's re-registration is what the caller writes: refused, the study is.
    let first = reregister(calibrated, &poses[..fit.min(poses.len())], &c)?;
    for k in 0..blocks {
        let block = k * fit..((k + 1) * fit).min(poses.len());
        let fitted = &poses[block.clone()];
        let scored: Vec<ArmPose> = poses
            .iter()
            .enumerate()
            .filter(|(i, _)| !block.contains(i))
            .map(|(_, p)| p.clone())
            .collect();
        for row in &mut rows {
            let result = match row.method {
                CampaignMethod::Reregistered if k == 0 => Ok(first.clone()),
                CampaignMethod::Reregistered => reregister(calibrated, fitted, &c),
                CampaignMethod::FullCalibration => calibrate_arm(nominal, fitted, &c),
                CampaignMethod::NominalRegistered => reregister(nominal, fitted, &c),
            };
            match result {
                Ok(cal) => {
                    let mean = |v: Vec<f64>| Summary::of(&v).map(|s| s.mean * 1e3);
                    row.position_um
                        .push(mean(arm_position_errors(&cal.arm, &scored)));
                    row.orientation_mdeg
                        .push(mean(arm_orientation_errors(&cal.arm, &scored)));
                }
                Err(e) => {
                    row.position_um.push(None);
                    row.orientation_mdeg.push(None);
                    row.refused.get_or_insert_with(|| e.to_string());
                }
            }
        }
    }
    Ok(CampaignStudy {
        fit,
        scored: poses.len() - fit.min(poses.len()),
        rows,
        first,
    })
}

impl CampaignStudy {
    /// The table: per method, the mean ± sample SD over blocks of each block's mean
    /// error on the poses it did not fit.
    pub fn markdown(&self) -> String {
        let cell = |v: &[Option<f64>]| {
            let got: Vec<f64> = v.iter().flatten().copied().collect();
            let missing = v.len() - got.len();
            match got.len() {
                0 => "refused".to_string(),
                1 => format!("{:.1}", got[0]),
                _ if missing > 0 => format!("{} ({missing} refused)", Spread::of(&got).text(1)),
                _ => Spread::of(&got).text(1),
            }
        };
        let blocks = self.rows.first().map_or(0, |r| r.position_um.len());
        let mut out = format!(
            "| {} poses fitted, the other {} scored ({blocks} block{}) | position, mean µm | orientation, mean mdeg |\n|---|---|---|\n",
            self.fit,
            self.scored,
            if blocks == 1 { "" } else { "s" }
        );
        for r in &self.rows {
            out.push_str(&format!(
                "| {} | {} | {} |\n",
                r.method.label(),
                cell(&r.position_um),
                if r.orientation_mdeg.iter().all(Option::is_none) && r.refused.is_none() {
                    "–".to_string()
                } else {
                    cell(&r.orientation_mdeg)
                }
            ));
        }
        for r in &self.rows {
            if let Some(why) = &r.refused {
                out.push_str(&format!(
                    "\n{}: refused on some blocks: {why}\n",
                    r.method.label()
                ));
            }
        }
        out
    }
}

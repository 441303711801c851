//! Rest hold: the weightless arm stays where the operator leaves it, despite model error.
//!
//! Zero-moment mode asks the drives for the model's torque and nothing else, so a static model
//! error δ (the gravity of a payload estimated from a short run, a few tenths of a per cent of
//! the load) is a torque nobody balances: the arm creeps at δ over the damping, about a
//! millimetre in 5 s at the tool for 0.2 N·m on a wrist joint. A real gearbox's stiction would
//! hold it; the model's friction compensation takes exactly that stiction away.
//!
//! This module gives the arm a stiction of its own, bounded by what the model does not know.
//! Per joint, an elasto-plastic element (the Dahl / "reset integrator" friction model) between
//! the joint and an anchor:
//!
//! ```text
//! τ_h = clip(k (a - q), ±band),   k = band / deflection,
//! ```
//!
//! whose anchor slides with the joint whenever the clip is active, so the element never pushes
//! more than `band`. A static error below the band deflects the arm by at most δ/k (less than
//! `deflection`) and it stays, however long. A push above the band moves the arm, against a
//! constant `band` (a Coulomb friction the operator pays; the product has no way to tell a
//! hand that pushes less than the model's error from the error itself), and when the push
//! falls below the band the arm stops. τ_h has no step.
//!
//! `band` per joint is what the model does not know: `rms_factor` × the model's held-out RMS
//! on that joint (`heldout_rms_nm` of an identified `model.json`), at least the configured
//! floor. The operator pays it as that Coulomb friction whenever a joint moves; a band of 2 RMS
//! on the GR630ST's J2 is about 2 N·m, a newton at the tool, and all six joints together cost
//! about 2-4 N of mean force on teach-bench's raster path.

use crate::chain::MAX_JOINTS;

/// The elasto-plastic hold, one call per cycle.
#[derive(Clone, Debug)]
pub struct RestHold {
    n: usize,
    band_nm: [f64; MAX_JOINTS],
    deflection_rad: f64,
    anchor_rad: [f64; MAX_JOINTS],
    /// false: the next step anchors every joint where it is
    anchored: bool,
}

impl RestHold {
    /// A hold of `band_nm` per joint [N·m] (finite, >= 0), reached at `deflection_rad` [rad]
    /// (finite, > 0).
    pub fn new(band_nm: &[f64], deflection_rad: f64) -> Result<RestHold, String> {
        if !(deflection_rad.is_finite() && deflection_rad > 0.0) {
            return Err(format!(
                "rest hold deflection {deflection_rad:?} must be > 0"
            ));
        }
        if !band_nm.iter().all(|b| b.is_finite() && *b >= 0.0) {
            return Err(format!("rest hold band {band_nm:?} must be >= 0 per joint"));
        }
        let n = band_nm.len();
        if n > MAX_JOINTS {
            return Err(format!(
                "rest hold band has {n} joints, at most {MAX_JOINTS}"
            ));
        }
        let mut band = [0.0; MAX_JOINTS];
        band[..n].copy_from_slice(band_nm);
        Ok(RestHold {
            n,
            band_nm: band,
            deflection_rad,
            anchor_rad: [0.0; MAX_JOINTS],
            anchored: false,
        })
    }

    pub fn n(&self) -> usize {
        self.n
    }

    pub fn band_nm(&self) -> &[f64] {
        &self.band_nm[..self.n]
    }

    pub fn deflection_rad(&self) -> f64 {
        self.deflection_rad
    }

    /// Some joint holds (a band above 0).
    pub fn active(&self) -> bool {
        self.band_nm().iter().any(|b| *b > 0.0)
    }

    /// Start afresh: the next step anchors every joint where it is (τ_h = 0).
    pub fn reset(&mut self) {
        self.anchored = false;
    }

    /// τ_h per joint [N·m] at the joint positions `q` [rad], into `out` (rate-independent:
    /// the element depends on the path of q, not on time).
    pub fn torque_nm(&mut self, q: &[f64], out: &mut [f64]) -> Result<(), String> {
        let n = self.n;
        if q.len() != n || out.len() != n {
            return Err(format!("q needs {n} values, got {}", q.len()));
        }
        if !self.anchored {
            self.anchor_rad[..n].copy_from_slice(q);
            self.anchored = true;
        }
        let limit = self.deflection_rad;
        for j in 0..n {
            let (qj, anchor) = (q[j], &mut self.anchor_rad[j]);
            let mut gap = *anchor - qj;
            if gap > limit {
                // the element slips: the anchor follows the joint
                gap = limit;
                *anchor = qj + limit;
            } else if gap < -limit {
                gap = -limit;
                *anchor = qj - limit;
            }
            out[j] = self.band_nm[j] * gap / limit;
        }
        Ok(())
    }
}

/// Per joint: `rms_factor` × the model's held-out RMS, at least `floor_nm` [N·m] (the floor
/// alone without a held-out RMS). Setup-time arithmetic.
pub fn hold_band_nm(
    floor_nm: &[f64],
    rms_factor: f64,
    heldout_rms_nm: Option<&[f64]>,
) -> Result<Vec<f64>, String> {
    let Some(rms) = heldout_rms_nm else {
        return Ok(floor_nm.to_vec());
    };
    if rms.len() != floor_nm.len() {
        return Err(format!(
            "model held-out RMS has {} joints, not {}",
            rms.len(),
            floor_nm.len()
        ));
    }
    // Python's max(f, x): x only where it is greater (a NaN floor stays, a NaN x loses)
    Ok(floor_nm
        .iter()
        .zip(rms)
        .map(|(&f, &r)| {
            let x = rms_factor * r;
            if x > f {
                x
            } else {
                f
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn torque(h: &mut RestHold, q: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; q.len()];
        h.torque_nm(q, &mut out).unwrap();
        out
    }

    #[test]
    fn the_element_springs_up_to_the_band_then_slides() {
        let mut h = RestHold::new(&[1.0, 0.0], 1e-3).unwrap();
        assert!(h.active());
        assert_eq!(torque(&mut h, &[0.0, 0.0]), [0.0, 0.0]);
        assert_eq!(torque(&mut h, &[0.0005, 0.3]), [-0.5, 0.0]);
        // past the deflection the anchor follows: the torque stays at the band
        assert_eq!(torque(&mut h, &[0.01, 0.3]), [-1.0, 0.0]);
        let back = torque(&mut h, &[0.0095, 0.3]);
        assert!((back[0] - -0.5).abs() < 1e-9, "{back:?}");
        h.reset();
        assert_eq!(torque(&mut h, &[0.2, 0.3]), [0.0, 0.0]);
    }

    #[test]
    fn bad_settings_and_sizes_are_refused() {
        assert!(RestHold::new(&[-1.0], 1e-3)
            .unwrap_err()
            .contains("rest hold band"));
        assert!(RestHold::new(&[f64::NAN], 1e-3).is_err());
        assert!(RestHold::new(&[1.0], 0.0)
            .unwrap_err()
            .contains("deflection"));
        assert!(RestHold::new(&[1.0], f64::INFINITY).is_err());
        assert!(!RestHold::new(&[0.0], 1e-3).unwrap().active());
        let mut h = RestHold::new(&[1.0], 1e-3).unwrap();
        assert!(h.torque_nm(&[0.0, 0.0], &mut [0.0, 0.0]).is_err());
    }

    #[test]
    fn the_band_is_the_scaled_rms_with_a_floor() {
        let band = hold_band_nm(&[0.5, 0.0], 2.0, Some(&[0.1, 0.4])).unwrap();
        assert_eq!(band, [0.5, 0.8]);
        assert_eq!(hold_band_nm(&[0.5, 0.0], 2.0, None).unwrap(), [0.5, 0.0]);
        let err = hold_band_nm(&[0.0; 3], 2.0, Some(&[0.1, 0.2])).unwrap_err();
        assert!(err.contains("2 joints, not 3"), "{err}");
    }
}

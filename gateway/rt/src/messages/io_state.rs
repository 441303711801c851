//! IoState, the cylinder pressures and safety inputs as the Modbus driver reads them
//! (messages.rs): both binary layouts (with and without the mark button), with every check of
//! gateway/messages.py.

use super::wire::{check_finite, check_header, f64_at, MessageError, LAYOUT_VERSION};

/// Cylinder pressures and safety inputs as the Modbus driver reads them (gateway/messages.py
/// IoState).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IoState {
    /// Modbus driver monotonic time of the poll [s]
    pub stamp_s: f64,
    /// measured pressure, assist cylinder of joint 2 [bar]
    pub p2_bar: f64,
    /// measured pressure, assist cylinder of joint 3 [bar]
    pub p3_bar: f64,
    /// set-point read back from the valve [bar]
    pub p2_set_bar: f64,
    /// set-point read back from the valve [bar]
    pub p3_set_bar: f64,
    /// enabling device held (3-position switch in its middle position)
    pub enabling: bool,
    /// e-stop chain closed (false: e-stop pressed or wire broken)
    pub estop_ok: bool,
    /// the teach handle's mark button pressed (false: no such button)
    pub mark: bool,
}

impl IoState {
    pub const MAGIC: &'static [u8; 4] = b"LTIO";
    /// `<4sBdddddBBB` [bytes].
    pub const SIZE: usize = 48;
    /// `<4sBdddddBB`, the layout before the mark button (read as "not pressed") [bytes].
    pub const SIZE_NO_MARK: usize = 47;

    /// The wire bytes (the current layout, with the mark button).
    pub fn to_bytes(&self) -> [u8; Self::SIZE] {
        let mut out = [0u8; Self::SIZE];
        out[..4].copy_from_slice(Self::MAGIC);
        out[4] = LAYOUT_VERSION;
        let values = [
            self.stamp_s,
            self.p2_bar,
            self.p3_bar,
            self.p2_set_bar,
            self.p3_set_bar,
        ];
        for (k, v) in values.iter().enumerate() {
            out[5 + 8 * k..13 + 8 * k].copy_from_slice(&v.to_le_bytes());
        }
        out[45] = self.enabling as u8;
        out[46] = self.estop_ok as u8;
        out[47] = self.mark as u8;
        out
    }

    /// Decode either layout with every check of Python's `IoState.from_bytes`.
    pub fn from_bytes(data: &[u8]) -> Result<IoState, MessageError> {
        check_header(data, Self::MAGIC, "IoState", 5, LAYOUT_VERSION)?;
        let mark = match data.len() {
            Self::SIZE => data[47],
            Self::SIZE_NO_MARK => 0,
            size => {
                return Err(MessageError(format!(
                    "IoState: {size} bytes, expected {}",
                    Self::SIZE
                )))
            }
        };
        let values = [
            f64_at(data, 5),
            f64_at(data, 13),
            f64_at(data, 21),
            f64_at(data, 29),
            f64_at(data, 37),
        ];
        check_finite("IoState(stamp, p2, p3, p2_set, p3_set)", &values)?;
        let (en, es) = (data[45], data[46]);
        if en > 1 || es > 1 || mark > 1 {
            return Err(MessageError(format!(
                "IoState: flags enabling={en} estop_ok={es} mark={mark} must be 0 or 1"
            )));
        }
        Ok(IoState {
            stamp_s: values[0],
            p2_bar: values[1],
            p3_bar: values[2],
            p2_set_bar: values[3],
            p3_set_bar: values[4],
            enabling: en == 1,
            estop_ok: es == 1,
            mark: mark == 1,
        })
    }
}

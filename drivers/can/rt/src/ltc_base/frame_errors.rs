//! The receiver's errors of §8 in words (ltc_base.rs): ltc_protocol.py's FrameError texts of
//! an [`LtcError`], and the count of bad frames whose last text the stats keep.

use std::fmt::Write;

use super::{Crc, LtcBase, LtcError};
use crate::adapter::AdapterStats;

impl LtcBase {
    /// ltc_protocol.py's FrameError text of `e`, appended to `out`.
    pub(crate) fn write_error(&self, e: &LtcError, out: &mut String) {
        let protocol = self.protocol;
        let _ = match *e {
            LtcError::ErrorFrame { id } => write!(
                out,
                "CAN error frame received (id field 0x{id:X}): the interface reported a bus \
                 error, not a data frame"
            ),
            LtcError::Extended { spec, id } => write!(
                out,
                "{}: arrived with an extended 29-bit id 0x{id:08X}; {protocol} uses standard \
                 11-bit ids only",
                self.specs[spec].codec.label
            ),
            LtcError::Remote { spec } => write!(
                out,
                "{}: remote (RTR) frame; {protocol} never uses remote frames",
                self.specs[spec].codec.label
            ),
            LtcError::FdMismatch { spec, fd } => {
                let label = &self.specs[spec].codec.label;
                if self.classic {
                    write!(out, "{label}: CAN FD frame; {protocol} is classic CAN")
                } else if fd {
                    write!(
                        out,
                        "{label}: CAN FD frame; {protocol} sends it as classic CAN"
                    )
                } else {
                    write!(
                        out,
                        "{label}: classic CAN frame; {protocol} sends it as CAN FD"
                    )
                }
            }
            LtcError::Dlc { spec, len } => {
                let c = &self.specs[spec].codec;
                write!(
                    out,
                    "{}: DLC {len} with {len} data bytes, expected {}",
                    c.label, c.length
                )
            }
            LtcError::Crc { spec, got, want } => {
                let s = &self.specs[spec];
                let k = s.crc.map_or(1, Crc::bytes);
                write!(
                    out,
                    "{}: CRC 0x{got:0w$X} does not match 0x{want:0w$X} computed over the id and \
                     data bytes 0..{}",
                    s.codec.label,
                    s.codec.length - k - 1,
                    w = 2 * k
                )
            }
            LtcError::Codec { spec, error } => {
                self.specs[spec].codec.write_decode_error(&error, out);
                Ok(())
            }
            LtcError::UnknownEnum {
                spec,
                signal,
                value,
                which,
            } => {
                let c = &self.specs[spec].codec;
                let _ = write!(
                    out,
                    "{}: {} = {value} is not a known value (",
                    c.label, c.signals[signal].name
                );
                for (k, (v, n)) in which.members().iter().enumerate() {
                    let _ = write!(out, "{}{v} {n}", if k > 0 { ", " } else { "" });
                }
                out.write_char(')')
            }
        };
    }

    /// Count a bad frame and make its text the stats' `last_error` (buffer reused).
    pub(crate) fn count_bad(&self, e: &LtcError, stats: &mut AdapterStats) {
        stats.bad_frames += 1;
        stats.last_error.clear();
        self.write_error(e, &mut stats.last_error);
    }
}

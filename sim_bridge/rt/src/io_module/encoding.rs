//! The module's register encodings, deliberately mixed so the driver's register map is
//! exercised end to end: measured p2 as an IEEE float32 (words and bytes big-endian, "ABCD"),
//! measured p3 as saturating uint16 mbar, set-points as int32 mbar with the low word first
//! ("CDAB"). Written here independently of the driver's `drivers/modbus/registermap.py`, so a
//! symmetric bug in the map cannot hide itself.

/// p2 [bar] as two registers, float32 "ABCD". A finite value beyond float32's range is sent as
/// the infinity of its sign (the nearest float32 a transmitter's ADC would report).
pub fn float32_abcd(bar: f64) -> [u16; 2] {
    let bits = (bar as f32).to_bits(); // round to nearest; out of range -> +-inf, NaN -> NaN
    [(bits >> 16) as u16, bits as u16]
}

/// p3 [bar] as one register of mbar, saturating at 0 and 65535; NaN (a transmitter with a
/// broken bridge) reads 65535, over-range.
pub fn mbar_uint16(bar: f64) -> u16 {
    if bar.is_nan() {
        return u16::MAX;
    }
    (bar * 1000.0).round_ties_even().clamp(0.0, u16::MAX as f64) as u16
}

/// A set-point [bar] as the module stores it: int32 mbar, saturating at int32's range (NaN: 0).
pub fn mbar_int32(bar: f64) -> i32 {
    let mbar = (bar * 1000.0).round_ties_even();
    if mbar.is_nan() {
        return 0;
    }
    mbar.clamp(i32::MIN as f64, i32::MAX as f64) as i32
}

/// An int32 as two registers, low word first ("CDAB").
pub fn int32_cdab(value: i32) -> [u16; 2] {
    let bits = value as u32;
    [bits as u16, (bits >> 16) as u16]
}

/// Two registers "CDAB" as the int32 they hold.
pub fn cdab_int32(regs: [u16; 2]) -> i32 {
    ((regs[1] as u32) << 16 | regs[0] as u32) as i32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn float32_is_big_endian_words_and_bytes() {
        assert_eq!(float32_abcd(1.5), [0x3FC0, 0x0000]);
        assert_eq!(float32_abcd(-2.0), [0xC000, 0x0000]);
        assert_eq!(float32_abcd(1e300), [0x7F80, 0x0000]); // +inf
        assert_eq!(float32_abcd(-1e300), [0xFF80, 0x0000]);
        let nan = float32_abcd(f64::NAN);
        assert_eq!(nan[0] & 0x7F80, 0x7F80);
        assert!(nan[0] & 0x007F != 0 || nan[1] != 0);
    }

    #[test]
    fn uint16_mbar_saturates_and_reports_nan_over_range() {
        assert_eq!(mbar_uint16(3.25), 3250);
        assert_eq!(mbar_uint16(-0.2), 0);
        assert_eq!(mbar_uint16(70.0), 65535);
        assert_eq!(mbar_uint16(f64::INFINITY), 65535);
        assert_eq!(mbar_uint16(f64::NEG_INFINITY), 0);
        assert_eq!(mbar_uint16(f64::NAN), 65535);
        assert_eq!(mbar_uint16(1.0004), 1000);
        assert_eq!(mbar_uint16(1.0006), 1001);
    }

    #[test]
    fn int32_is_low_word_first_and_round_trips() {
        assert_eq!(int32_cdab(4200), [4200, 0]);
        assert_eq!(int32_cdab(-1), [0xFFFF, 0xFFFF]);
        assert_eq!(int32_cdab(0x0001_0002), [2, 1]);
        for v in [0, 1, -1, 1500, -123_456, i32::MAX, i32::MIN] {
            assert_eq!(cdab_int32(int32_cdab(v)), v);
        }
        assert_eq!(mbar_int32(1.5), 1500);
        assert_eq!(mbar_int32(-0.001), -1);
        assert_eq!(mbar_int32(1e12), i32::MAX);
        assert_eq!(mbar_int32(f64::NAN), 0);
    }
}

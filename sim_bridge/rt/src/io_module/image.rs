//! What the module holds: the inputs the simulator sets every cycle, the set-points and coils
//! its clients write. Shared between the simulator's thread and the server's threads; each
//! request reads one consistent snapshot of the inputs.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use super::encoding::{cdab_int32, float32_abcd, int32_cdab, mbar_int32, mbar_uint16};

/// Input registers (p2 float32, p3 uint16), holding registers (two int32 set-points), and
/// the bits of the discrete inputs and coils (16 each, as the manual lists).
pub const N_INPUT_REGISTERS: usize = 3;
pub const N_HOLDING_REGISTERS: usize = 4;
pub const N_BITS: usize = 16;

/// The simulator's side of the module: the measured pressures [bar] and the switches.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Inputs {
    pub p2_bar: f64,
    pub p3_bar: f64,
    pub enabling: bool,
    pub estop_ok: bool,
    pub mark: bool,
}

struct Written {
    holding: [u16; N_HOLDING_REGISTERS],
    coils: [bool; N_BITS],
}

/// The module's state; `&Module` is all a request needs.
pub struct Module {
    inputs: Mutex<Inputs>,
    written: Mutex<Written>,
    setpoint_writes: AtomicU64,
}

fn locked<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    // a panic elsewhere cannot leave these plain values half-updated: keep serving
    m.lock().unwrap_or_else(|poison| poison.into_inner())
}

impl Module {
    /// A module holding the set-points `p2_set_bar`, `p3_set_bar` before any client writes
    /// (the valves power up holding them), every input zero or off.
    pub fn new(p2_set_bar: f64, p3_set_bar: f64) -> Module {
        let [a, b] = int32_cdab(mbar_int32(p2_set_bar));
        let [c, d] = int32_cdab(mbar_int32(p3_set_bar));
        Module {
            inputs: Mutex::new(Inputs::default()),
            written: Mutex::new(Written {
                holding: [a, b, c, d],
                coils: [false; N_BITS],
            }),
            setpoint_writes: AtomicU64::new(0),
        }
    }

    pub fn set_inputs(&self, inputs: Inputs) {
        *locked(&self.inputs) = inputs;
    }

    pub fn inputs(&self) -> Inputs {
        *locked(&self.inputs)
    }

    /// The set-points [bar] as stored (int32 mbar), the initial ones until a client writes.
    pub fn setpoints_bar(&self) -> (f64, f64) {
        let h = locked(&self.written).holding;
        (
            cdab_int32([h[0], h[1]]) as f64 / 1000.0,
            cdab_int32([h[2], h[3]]) as f64 / 1000.0,
        )
    }

    /// Write requests that reached the set-points.
    pub fn setpoint_writes(&self) -> u64 {
        self.setpoint_writes.load(Ordering::Relaxed)
    }

    /// The input registers, encoded from the inputs as they are now.
    pub fn input_registers(&self) -> [u16; N_INPUT_REGISTERS] {
        let i = self.inputs();
        let [hi, lo] = float32_abcd(i.p2_bar);
        [hi, lo, mbar_uint16(i.p3_bar)]
    }

    /// The discrete inputs: enabling, e-stop chain, mark; the rest read 0.
    pub fn discrete_inputs(&self) -> [bool; N_BITS] {
        let i = self.inputs();
        let mut bits = [false; N_BITS];
        bits[0] = i.enabling;
        bits[1] = i.estop_ok;
        bits[2] = i.mark;
        bits
    }

    pub fn holding_registers(&self) -> [u16; N_HOLDING_REGISTERS] {
        locked(&self.written).holding
    }

    pub fn coils(&self) -> [bool; N_BITS] {
        locked(&self.written).coils
    }

    /// Store `values` from holding register `first` on (the caller checked the range), stored
    /// as written: the driver owns the limits.
    pub fn write_holding(&self, first: usize, values: &[u16]) {
        locked(&self.written).holding[first..first + values.len()].copy_from_slice(values);
        self.setpoint_writes.fetch_add(1, Ordering::Relaxed);
    }

    pub fn write_coils(&self, first: usize, values: &[bool]) {
        locked(&self.written).coils[first..first + values.len()].copy_from_slice(values);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn initial_setpoints_are_stored_in_mbar_and_writes_replace_them() {
        let m = Module::new(1.5, 2.0);
        assert_eq!(m.holding_registers(), [1500, 0, 2000, 0]);
        assert_eq!(m.setpoints_bar(), (1.5, 2.0));
        m.write_holding(0, &[4200, 0, 0xFFFF, 0xFFFF]);
        assert_eq!(m.setpoints_bar(), (4.2, -0.001));
        m.write_holding(2, &[5125, 0]);
        assert_eq!(m.setpoints_bar(), (4.2, 5.125));
        assert_eq!(m.setpoint_writes(), 2);
    }

    #[test]
    fn inputs_are_encoded_when_read() {
        let m = Module::new(0.0, 0.0);
        m.set_inputs(Inputs {
            p2_bar: 1.5,
            p3_bar: 3.25,
            enabling: true,
            estop_ok: false,
            mark: true,
        });
        assert_eq!(m.input_registers(), [0x3FC0, 0, 3250]);
        let bits = m.discrete_inputs();
        assert_eq!(&bits[..4], &[true, false, true, false]);
    }
}

//! One request PDU (function code and data) answered: the functions of the Modbus Application
//! Protocol V1.1b3 §6 an I/O module serves over its tables, with the spec's exception codes.
//!
//! Tables and their sizes are the manual's ([`super::image`]); a request reaching past a table
//! answers ILLEGAL DATA ADDRESS, a quantity outside the spec's limits or a malformed request
//! ILLEGAL DATA VALUE, any other function ILLEGAL FUNCTION.

use super::image::{Module, N_BITS, N_HOLDING_REGISTERS, N_INPUT_REGISTERS};

pub const ILLEGAL_FUNCTION: u8 = 1;
pub const ILLEGAL_DATA_ADDRESS: u8 = 2;
pub const ILLEGAL_DATA_VALUE: u8 = 3;
pub const SERVER_DEVICE_FAILURE: u8 = 4;

const READ_COILS: u8 = 1;
const READ_DISCRETE_INPUTS: u8 = 2;
const READ_HOLDING: u8 = 3;
const READ_INPUT: u8 = 4;
const WRITE_COIL: u8 = 5;
const WRITE_REGISTER: u8 = 6;
const WRITE_COILS: u8 = 15;
const WRITE_REGISTERS: u8 = 16;
const READ_WRITE_REGISTERS: u8 = 23;

/// The exception response to function `function`.
pub fn exception(function: u8, code: u8, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&[function | 0x80, code]);
}

fn u16_at(data: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([data[at], data[at + 1]])
}

/// `first .. first + count` within a table of `size` entries, `count` within `1..=max`.
fn check_range(first: u16, count: u16, max: u16, size: usize) -> Result<usize, u8> {
    if count == 0 || count > max {
        return Err(ILLEGAL_DATA_VALUE);
    }
    if first as usize + count as usize > size {
        return Err(ILLEGAL_DATA_ADDRESS);
    }
    Ok(first as usize)
}

fn push_bits(bits: &[bool], out: &mut Vec<u8>) {
    out.push(bits.len().div_ceil(8) as u8);
    for chunk in bits.chunks(8) {
        out.push(
            chunk
                .iter()
                .enumerate()
                .fold(0u8, |b, (k, &on)| b | (u8::from(on) << k)),
        );
    }
}

fn push_registers(regs: &[u16], out: &mut Vec<u8>) {
    out.push((2 * regs.len()) as u8);
    for r in regs {
        out.extend_from_slice(&r.to_be_bytes());
    }
}

/// Answer `pdu` (function code first) from `module` into `out` (cleared first): the response
/// PDU, normal or exception. An empty `pdu` answers nothing (`out` stays empty).
pub fn answer(module: &Module, pdu: &[u8], out: &mut Vec<u8>) {
    out.clear();
    let Some((&function, data)) = pdu.split_first() else {
        return;
    };
    if let Err(code) = serve(module, function, data, out) {
        exception(function, code, out);
    }
}

fn serve(module: &Module, function: u8, data: &[u8], out: &mut Vec<u8>) -> Result<(), u8> {
    let fixed = |len: usize| {
        if data.len() == len {
            Ok(())
        } else {
            Err(ILLEGAL_DATA_VALUE)
        }
    };
    out.push(function);
    match function {
        READ_COILS | READ_DISCRETE_INPUTS => {
            fixed(4)?;
            let first = check_range(u16_at(data, 0), u16_at(data, 2), 2000, N_BITS)?;
            let count = u16_at(data, 2) as usize;
            let bits = if function == READ_COILS {
                module.coils()
            } else {
                module.discrete_inputs()
            };
            push_bits(&bits[first..first + count], out);
        }
        READ_HOLDING | READ_INPUT => {
            fixed(4)?;
            let (size, regs) = if function == READ_HOLDING {
                (N_HOLDING_REGISTERS, module.holding_registers().to_vec())
            } else {
                (N_INPUT_REGISTERS, module.input_registers().to_vec())
            };
            let first = check_range(u16_at(data, 0), u16_at(data, 2), 125, size)?;
            push_registers(&regs[first..first + u16_at(data, 2) as usize], out);
        }
        WRITE_COIL => {
            fixed(4)?;
            let on = match u16_at(data, 2) {
                0xFF00 => true,
                0x0000 => false,
                _ => return Err(ILLEGAL_DATA_VALUE),
            };
            let first = check_range(u16_at(data, 0), 1, 1, N_BITS)?;
            module.write_coils(first, &[on]);
            out.extend_from_slice(data); // the echo of the request
        }
        WRITE_REGISTER => {
            fixed(4)?;
            let first = check_range(u16_at(data, 0), 1, 1, N_HOLDING_REGISTERS)?;
            module.write_holding(first, &[u16_at(data, 2)]);
            out.extend_from_slice(data);
        }
        WRITE_COILS => {
            let (first, count) = write_header(data, 1968, |n| n.div_ceil(8), N_BITS)?;
            let bytes = &data[5..];
            let bits: Vec<bool> = (0..count)
                .map(|k| bytes[k / 8] >> (k % 8) & 1 == 1)
                .collect();
            module.write_coils(first, &bits);
            out.extend_from_slice(&data[..4]);
        }
        WRITE_REGISTERS => {
            let (first, count) = write_header(data, 123, |n| 2 * n, N_HOLDING_REGISTERS)?;
            module.write_holding(first, &registers(&data[5..], count));
            out.extend_from_slice(&data[..4]);
        }
        READ_WRITE_REGISTERS => {
            if data.len() < 9 {
                return Err(ILLEGAL_DATA_VALUE);
            }
            let (read_first, read_count) = (u16_at(data, 0), u16_at(data, 2));
            let (first, count) = write_header(&data[4..], 121, |n| 2 * n, N_HOLDING_REGISTERS)?;
            let read = check_range(read_first, read_count, 125, N_HOLDING_REGISTERS)?;
            module.write_holding(first, &registers(&data[9..], count)); // write, then read
            let regs = module.holding_registers();
            push_registers(&regs[read..read + read_count as usize], out);
        }
        _ => return Err(ILLEGAL_FUNCTION),
    }
    Ok(())
}

/// A write request's address, quantity and byte count (`data`: from the address on), checked
/// against the quantity's limit `max`, the bytes the quantity needs and the table's `size`.
fn write_header(
    data: &[u8],
    max: u16,
    bytes_for: impl Fn(usize) -> usize,
    size: usize,
) -> Result<(usize, usize), u8> {
    if data.len() < 5 {
        return Err(ILLEGAL_DATA_VALUE);
    }
    let (first, count, byte_count) = (u16_at(data, 0), u16_at(data, 2), data[4] as usize);
    if count == 0 || count > max {
        return Err(ILLEGAL_DATA_VALUE);
    }
    if byte_count != bytes_for(count as usize) || data.len() != 5 + byte_count {
        return Err(ILLEGAL_DATA_VALUE);
    }
    Ok((check_range(first, count, max, size)?, count as usize))
}

fn registers(bytes: &[u8], count: usize) -> Vec<u16> {
    (0..count).map(|k| u16_at(bytes, 2 * k)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io_module::Inputs;

    fn ask(m: &Module, pdu: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        answer(m, pdu, &mut out);
        out
    }

    fn module() -> Module {
        let m = Module::new(1.5, 2.0);
        m.set_inputs(Inputs {
            p2_bar: 1.5,
            p3_bar: 3.25,
            enabling: true,
            estop_ok: false,
            mark: false,
        });
        m
    }

    #[test]
    fn protocol_address_0_is_the_first_value_of_each_table() {
        let m = module();
        assert_eq!(
            ask(&m, &[4, 0, 0, 0, 3]),
            [4, 6, 0x3F, 0xC0, 0, 0, 0x0C, 0xB2]
        );
        assert_eq!(ask(&m, &[4, 0, 2, 0, 1]), [4, 2, 0x0C, 0xB2]);
        assert_eq!(
            ask(&m, &[3, 0, 0, 0, 4]),
            [3, 8, 0x05, 0xDC, 0, 0, 0x07, 0xD0, 0, 0]
        );
        assert_eq!(ask(&m, &[2, 0, 0, 0, 2]), [2, 1, 0b01]);
        assert_eq!(ask(&m, &[2, 0, 0, 0, 16]), [2, 2, 0b01, 0]);
        assert_eq!(ask(&m, &[1, 0, 0, 0, 1]), [1, 1, 0]);
    }

    #[test]
    fn requests_past_a_table_or_its_limits_are_refused_with_the_specs_codes() {
        let m = module();
        assert_eq!(ask(&m, &[4, 0, 2, 0, 5]), [0x84, ILLEGAL_DATA_ADDRESS]);
        assert_eq!(ask(&m, &[3, 0, 0, 0, 0]), [0x83, ILLEGAL_DATA_VALUE]);
        assert_eq!(ask(&m, &[3, 0, 0, 0, 126]), [0x83, ILLEGAL_DATA_VALUE]);
        assert_eq!(ask(&m, &[2, 0, 16, 0, 1]), [0x82, ILLEGAL_DATA_ADDRESS]);
        assert_eq!(ask(&m, &[3, 0, 0]), [0x83, ILLEGAL_DATA_VALUE]); // cut short
        assert_eq!(ask(&m, &[5, 0, 0, 0x12, 0x34]), [0x85, ILLEGAL_DATA_VALUE]);
        assert_eq!(ask(&m, &[43, 14, 1, 0]), [0xAB, ILLEGAL_FUNCTION]);
        assert_eq!(ask(&m, &[]), Vec::<u8>::new());
    }

    #[test]
    fn writes_reach_the_setpoints_and_coils_and_echo_the_request() {
        let m = module();
        let req = [16, 0, 0, 0, 4, 8, 0x10, 0x68, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF];
        assert_eq!(ask(&m, &req), [16, 0, 0, 0, 4]);
        assert_eq!(m.setpoints_bar(), (4.2, -0.001));
        assert_eq!(ask(&m, &[6, 0, 2, 0x14, 0x05]), [6, 0, 2, 0x14, 0x05]);
        assert_eq!(ask(&m, &[6, 0, 3, 0, 0]), [6, 0, 3, 0, 0]); // p3's high word
        assert_eq!(m.setpoints_bar(), (4.2, 5.125));
        assert_eq!(ask(&m, &[5, 0, 0, 0xFF, 0]), [5, 0, 0, 0xFF, 0]);
        assert_eq!(ask(&m, &[15, 0, 1, 0, 2, 1, 0b11]), [15, 0, 1, 0, 2]);
        assert_eq!(&m.coils()[..4], &[true, true, true, false]);
        // a byte count that does not match the quantity writes nothing
        assert_eq!(
            ask(&m, &[16, 0, 0, 0, 2, 3, 0, 0, 0]),
            [0x90, ILLEGAL_DATA_VALUE]
        );
        assert_eq!(m.setpoints_bar(), (4.2, 5.125));
        assert_eq!(
            ask(&m, &[16, 0, 3, 0, 2, 4, 0, 0, 0, 0]),
            [0x90, ILLEGAL_DATA_ADDRESS]
        );
    }

    #[test]
    fn read_write_registers_writes_first_then_reads() {
        let m = module();
        let req = [23, 0, 0, 0, 2, 0, 0, 0, 2, 4, 0x03, 0xE8, 0, 0];
        assert_eq!(ask(&m, &req), [23, 4, 0x03, 0xE8, 0, 0]);
        assert_eq!(m.setpoints_bar(), (1.0, 2.0));
    }
}

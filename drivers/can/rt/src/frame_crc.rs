//! The LTC protocols' end-to-end CRCs (drivers/can/PROTOCOL.md §4, §10.3): CRC-8/SAE-J1850 of
//! LTC-1's host frames and CRC-16/CCITT-FALSE of LTC-1F's CYCLE_CMD, each over the frame's two
//! little-endian identifier bytes and then its data. Shared by both adapters (ltc_adapter.rs,
//! ltc_fd_adapter.rs); ltc_frames.py and ltc_fd.py compute the same in Python.

// --- CRC-8/SAE-J1850 (§4) ---------------------------------------------------------------------
const fn crc8_table(poly: u8) -> [u8; 256] {
    let mut table = [0u8; 256];
    let mut byte = 0;
    while byte < 256 {
        let mut crc = byte as u8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x80 != 0 {
                (crc << 1) ^ poly
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[byte] = crc;
        byte += 1;
    }
    table
}

static CRC8_J1850: [u8; 256] = crc8_table(0x1D);

fn crc8_update(mut crc: u8, data: &[u8]) -> u8 {
    for &b in data {
        crc = CRC8_J1850[(crc ^ b) as usize];
    }
    crc
}

/// CRC-8/SAE-J1850: poly 0x1D, init 0xFF, not reflected, xorout 0xFF (check 0x4B).
pub fn crc8_sae_j1850(data: &[u8]) -> u8 {
    crc8_update(0xFF, data) ^ 0xFF
}

/// The two identifier bytes, little-endian, that start every LTC CRC's input (§4, §10.3).
pub fn id_bytes(id: u32) -> [u8; 2] {
    [(id & 0xFF) as u8, ((id >> 8) & 0xFF) as u8]
}

/// The CRC of an LTC-1 host frame: over the id bytes, then `data` (the bytes before the CRC).
pub fn frame_crc8(id: u32, data: &[u8]) -> u8 {
    crc8_update(crc8_update(0xFF, &id_bytes(id)), data) ^ 0xFF
}

// --- CRC-16/CCITT-FALSE (§10.3) ---------------------------------------------------------------
const fn crc16_table(poly: u16) -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut byte = 0;
    while byte < 256 {
        let mut crc = (byte as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ poly
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[byte] = crc;
        byte += 1;
    }
    table
}

static CRC16_CCITT: [u16; 256] = crc16_table(0x1021);

fn crc16_update(mut crc: u16, data: &[u8]) -> u16 {
    for &b in data {
        crc = (crc << 8) ^ CRC16_CCITT[((crc >> 8) as u8 ^ b) as usize];
    }
    crc
}

/// CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, not reflected, xorout 0 (check 0x29B1);
/// Python's `binascii.crc_hqx(data, 0xFFFF)`.
pub fn crc16_ccitt_false(data: &[u8]) -> u16 {
    crc16_update(0xFFFF, data)
}

/// The CRC of an LTC-1F CYCLE_CMD: over the two little-endian id bytes, then `data` (the data
/// bytes before the CRC, 0..45).
pub fn frame_crc16(id: u32, data: &[u8]) -> u16 {
    crc16_update(crc16_update(0xFFFF, &id_bytes(id)), data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc8_check_value_and_manual_examples() {
        assert_eq!(crc8_sae_j1850(b"123456789"), 0x4B);
        // PROTOCOL.md §4: JOINT_CMD_J1 example, CRC 0x4F; HOST_REQUEST SERVO_ON counter 7
        assert_eq!(
            frame_crc8(0x201, &[0xa0, 0x86, 0x01, 0x3c, 0xf6, 0x00, 0x2a]),
            0x4F
        );
        assert_eq!(frame_crc8(0x020, &[0x01, 0x07, 0, 0, 0, 0, 0]), 0xD2);
    }
}

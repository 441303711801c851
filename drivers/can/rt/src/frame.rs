//! One CAN frame as Linux SocketCAN carries it: `struct can_frame` (16 bytes) or
//! `struct canfd_frame` (72 bytes) of `<linux/can.h>`, host byte order. A SocketCAN raw socket
//! and our seqpacket transport (drivers/can/seqpacket.py) carry exactly these bytes, so one
//! codec serves both.

/// Extended frame format (29-bit id).
pub const CAN_EFF_FLAG: u32 = 0x8000_0000;
/// Remote transmission request.
pub const CAN_RTR_FLAG: u32 = 0x4000_0000;
/// Error message frame.
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;
pub const CAN_EFF_MASK: u32 = 0x1FFF_FFFF;
pub const CAN_SFF_MASK: u32 = 0x0000_07FF;
/// Bit rate switch.
pub const CANFD_BRS: u8 = 0x01;
/// Error state indicator of the transmitting node.
pub const CANFD_ESI: u8 = 0x02;
/// Marks a struct canfd_frame holding an FD frame.
pub const CANFD_FDF: u8 = 0x04;
/// sizeof(struct can_frame) [bytes].
pub const CAN_MTU: usize = 16;
/// sizeof(struct canfd_frame) [bytes].
pub const CANFD_MTU: usize = 72;
pub const CAN_MAX_DLEN: usize = 8;
pub const CANFD_MAX_DLEN: usize = 64;
/// Payload lengths a CAN FD frame can have (ISO 11898-1 DLC 0..15) [bytes].
pub const CANFD_LENGTHS: [usize; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// One frame. `Copy` and fixed-size: the cycle never allocates for a frame.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    /// The frame's id without flags (11 or 29 bits; an error frame's error class).
    pub id: u32,
    pub extended: bool,
    pub remote: bool,
    pub error: bool,
    /// A CAN FD frame (then `brs`, `esi` apply and `len` is a CAN FD length).
    pub fd: bool,
    pub brs: bool,
    pub esi: bool,
    /// Data bytes in use (a remote frame's DLC for a remote frame).
    pub len: u8,
    pub data: [u8; 64],
}

impl std::fmt::Debug for Frame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Frame(0x{:X}{}{}{}{} [",
            self.id,
            if self.extended { " ext" } else { "" },
            if self.remote { " rtr" } else { "" },
            if self.error { " err" } else { "" },
            if self.fd { " fd" } else { "" }
        )?;
        for (k, b) in self.payload().iter().enumerate() {
            write!(f, "{}{:02X}", if k > 0 { " " } else { "" }, b)?;
        }
        write!(f, "])")
    }
}

/// The smallest CAN FD length that holds `size` bytes (python-can pads the same).
pub fn fd_padded(size: usize) -> usize {
    CANFD_LENGTHS
        .iter()
        .copied()
        .find(|&n| n >= size)
        .unwrap_or(CANFD_MAX_DLEN)
}

impl Frame {
    /// A classic data frame with a standard (11-bit) id.
    pub fn classic(id: u32, data: &[u8]) -> Frame {
        let mut f = Frame::empty(id);
        f.len = data.len().min(CAN_MAX_DLEN) as u8;
        f.data[..f.len as usize].copy_from_slice(&data[..f.len as usize]);
        f
    }

    /// A CAN FD data frame with a standard id; the payload is zero-padded to an FD length.
    pub fn fd(id: u32, data: &[u8], brs: bool) -> Frame {
        let mut f = Frame::empty(id);
        let n = data.len().min(CANFD_MAX_DLEN);
        f.fd = true;
        f.brs = brs;
        f.len = fd_padded(n) as u8;
        f.data[..n].copy_from_slice(&data[..n]);
        f
    }

    /// A zero-length classic frame of `id` (standard).
    pub fn empty(id: u32) -> Frame {
        Frame {
            id,
            extended: false,
            remote: false,
            error: false,
            fd: false,
            brs: false,
            esi: false,
            len: 0,
            data: [0; 64],
        }
    }

    /// The data bytes in use (empty for a remote frame).
    pub fn payload(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            &self.data[..self.len as usize]
        }
    }

    /// The struct can_frame / canfd_frame bytes; returns how many of `buf` were written
    /// (16 or 72). Err for a frame no CAN bus could carry.
    pub fn to_wire(&self, buf: &mut [u8; CANFD_MTU]) -> Result<usize, String> {
        let limit = if self.extended || self.error {
            CAN_EFF_MASK
        } else {
            CAN_SFF_MASK
        };
        if self.id > limit {
            return Err(format!("id 0x{:X} out of range 0..0x{:X}", self.id, limit));
        }
        let mut can_id = self.id;
        if self.extended {
            can_id |= CAN_EFF_FLAG;
        }
        if self.error {
            can_id |= CAN_ERR_FLAG;
        }
        buf.fill(0);
        if self.fd {
            if self.remote {
                return Err("CAN FD has no remote frames".into());
            }
            let len = self.len as usize;
            if !CANFD_LENGTHS.contains(&len) {
                return Err(format!("FD len {len} is not a CAN FD length"));
            }
            let mut flags = CANFD_FDF;
            if self.brs {
                flags |= CANFD_BRS;
            }
            if self.esi {
                flags |= CANFD_ESI;
            }
            buf[..4].copy_from_slice(&can_id.to_ne_bytes());
            buf[4] = self.len;
            buf[5] = flags;
            buf[8..8 + len].copy_from_slice(&self.data[..len]);
            return Ok(CANFD_MTU);
        }
        if self.len as usize > CAN_MAX_DLEN {
            return Err(format!(
                "{} data bytes; a classic frame carries at most 8",
                self.len
            ));
        }
        if self.remote {
            can_id |= CAN_RTR_FLAG;
        }
        buf[..4].copy_from_slice(&can_id.to_ne_bytes());
        buf[4] = self.len;
        if !self.remote {
            buf[8..8 + self.len as usize].copy_from_slice(&self.data[..self.len as usize]);
        }
        Ok(CAN_MTU)
    }

    /// A received struct can_frame / canfd_frame; Err says what is wrong with the datagram.
    /// `fd_allowed` false: an FD frame is refused (a SocketCAN socket without
    /// CAN_RAW_FD_FRAMES never delivers one).
    pub fn from_wire(datagram: &[u8], fd_allowed: bool) -> Result<Frame, String> {
        let size = datagram.len();
        if size != CAN_MTU && size != CANFD_MTU {
            return Err(format!(
                "{size} bytes, neither a can_frame ({CAN_MTU}) nor a canfd_frame ({CANFD_MTU})"
            ));
        }
        let can_id = u32::from_ne_bytes([datagram[0], datagram[1], datagram[2], datagram[3]]);
        let len = datagram[4] as usize;
        let flags = datagram[5];
        let is_fd = size == CANFD_MTU;
        let mut f = Frame::empty(can_id & CAN_EFF_MASK);
        f.extended = can_id & CAN_EFF_FLAG != 0;
        f.error = can_id & CAN_ERR_FLAG != 0;
        f.remote = can_id & CAN_RTR_FLAG != 0;
        if is_fd {
            if !fd_allowed {
                return Err("an FD frame on a bus opened without fd".into());
            }
            if !CANFD_LENGTHS.contains(&len) {
                return Err(format!("FD len {len} is not a CAN FD length"));
            }
            if flags & !(CANFD_BRS | CANFD_ESI | CANFD_FDF) != 0 {
                return Err(format!("unknown FD flags 0x{flags:02X}"));
            }
            if f.remote {
                return Err("remote flag on an FD frame".into());
            }
            f.fd = true;
            f.brs = flags & CANFD_BRS != 0;
            f.esi = flags & CANFD_ESI != 0;
        } else if len > CAN_MAX_DLEN {
            return Err(format!("classic len {len} > 8"));
        }
        if f.id > CAN_SFF_MASK && !(f.extended || f.error) {
            return Err(format!(
                "standard id 0x{:X} > 0x7FF without CAN_EFF_FLAG",
                f.id
            ));
        }
        f.len = len as u8;
        if !f.remote {
            f.data[..len].copy_from_slice(&datagram[8..8 + len]);
        }
        Ok(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classic_and_fd_frames_survive_the_wire() {
        let mut buf = [0u8; CANFD_MTU];
        let f = Frame::classic(0x201, &[1, 2, 3, 4, 5, 6, 7, 8]);
        let n = f.to_wire(&mut buf).unwrap();
        assert_eq!(n, CAN_MTU);
        assert_eq!(Frame::from_wire(&buf[..n], false).unwrap(), f);
        let g = Frame::fd(0x180, &[9; 50], true);
        assert_eq!(g.len, 64);
        let n = g.to_wire(&mut buf).unwrap();
        assert_eq!(n, CANFD_MTU);
        assert_eq!(Frame::from_wire(&buf[..n], true).unwrap(), g);
        assert!(Frame::from_wire(&buf[..n], false).is_err());
    }

    #[test]
    fn malformed_datagrams_are_named() {
        assert!(Frame::from_wire(&[0u8; 15], true)
            .unwrap_err()
            .contains("15 bytes"));
        let mut d = [0u8; CAN_MTU];
        d[4] = 9;
        assert!(Frame::from_wire(&d, true)
            .unwrap_err()
            .contains("classic len 9"));
        d[4] = 0;
        d[..4].copy_from_slice(&0x800u32.to_ne_bytes());
        assert!(Frame::from_wire(&d, true)
            .unwrap_err()
            .contains("standard id"));
    }
}

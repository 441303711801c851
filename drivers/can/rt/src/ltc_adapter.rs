//! LTC-1, the robot controller's classic-CAN external-command protocol, seen from the host:
//! drivers/can/ltc.py's `LtcAdapter` compiled, bit for bit and text for text.
//!
//! Per control cycle the controller sends JOINT_FB_J1..Jn, then CTRL_STATUS, which closes the
//! cycle (PROTOCOL.md §3); the host answers with JOINT_CMD_J1..Jn. A cycle is returned only if
//! the status and every configured joint's feedback (with the status's counter low byte)
//! arrived valid since the previous status; one bad per-cycle frame or a bus error frame loses
//! the whole cycle (§8).
//!
//! [`LtcBase`] is what LTC-1 shares with its CAN FD profile LTC-1F (ltc_fd_adapter.rs), as
//! ltc_protocol.py's `LtcProtocolBase`: the tables' header and messages, the receiver's checks of
//! §8 (error frame, extended id, RTR, CAN FD or not, DLC, CRC, range, enums) with
//! ltc_protocol.py's error texts, HOST_REQUEST and the heartbeats (§7), and the CRC-8 of §4.
//!
//! Built by [`LtcAdapter::from_tables`] from drivers/can/rt_tables.py's `ltc_tables("ltc_dbc",
//! n)`; the cycle then allocates nothing: decoded values go to preallocated scratch, errors are
//! kept as `Copy` values and written into `last_error`'s reused buffer.

use std::fmt::Write;

use serde_json::Value;

use crate::adapter::{
    Adapter, AdapterStats, ControllerState, Feedback, FrameError, HostRequest, MAX_JOINTS,
};
use crate::codec::{self, DecodeError, MessageCodec};
use crate::frame::{Frame, CANFD_MAX_DLEN, CAN_SFF_MASK};
use crate::frame_crc::{frame_crc16, frame_crc8};

/// The table layout this code reads (rt_tables.py `TABLES_FORMAT`).
pub const TABLES_FORMAT: u64 = 1;

/// CTRL_STATUS.state's values (gateway/messages.py ControllerState).
pub const CONTROLLER_STATES: [(i64, &str); 4] =
    [(0, "BRAKED"), (1, "HOLD"), (2, "EXTERNAL"), (3, "FAULT")];
/// CTRL_STATUS.fault_code's values (ltc_frames.py FaultCode, PROTOCOL.md §6.2).
pub const FAULT_CODES: [(i64, &str); 7] = [
    (0, "NONE"),
    (1, "ESTOP"),
    (2, "CMD_TIMEOUT"),
    (3, "HOST_HEARTBEAT_LOST"),
    (4, "FOLLOWING_ERROR"),
    (5, "BAD_COMMAND"),
    (6, "JOINT_LIMIT"),
];
/// HOST_REQUEST.request's values (adapter.py HostRequest).
pub const HOST_REQUESTS: [(i64, &str); 3] = [(0, "BRAKE"), (1, "SERVO_ON"), (2, "RESET_FAULT")];
/// The heartbeats' NMT states (ltc_frames.py NmtState, CiA 301).
pub const NMT_STATES: [(i64, &str); 4] = [
    (0, "BOOT"),
    (4, "STOPPED"),
    (5, "OPERATIONAL"),
    (127, "PRE_OPERATIONAL"),
];

/// The enums LTC defines beside the DBC; the DBC's value tables must say the same
/// (ltc_protocol.py `check_enum_against_dbc`), and decoding refuses any other value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LtcEnum {
    ControllerState,
    FaultCode,
    HostRequest,
    NmtState,
}

impl LtcEnum {
    fn members(self) -> &'static [(i64, &'static str)] {
        match self {
            LtcEnum::ControllerState => &CONTROLLER_STATES,
            LtcEnum::FaultCode => &FAULT_CODES,
            LtcEnum::HostRequest => &HOST_REQUESTS,
            LtcEnum::NmtState => &NMT_STATES,
        }
    }

    fn type_name(self) -> &'static str {
        match self {
            LtcEnum::ControllerState => "ControllerState",
            LtcEnum::FaultCode => "FaultCode",
            LtcEnum::HostRequest => "HostRequest",
            LtcEnum::NmtState => "NmtState",
        }
    }

    /// The member's name for wire value `value`, None if it is not a member.
    pub(crate) fn name_of(self, value: i64) -> Option<&'static str> {
        self.members()
            .iter()
            .find(|(v, _)| *v == value)
            .map(|(_, n)| *n)
    }

    /// The wire value of the member called `name`.
    fn value_of(self, name: &str) -> Option<i64> {
        self.members()
            .iter()
            .find(|(_, n)| *n == name)
            .map(|(v, _)| *v)
    }
}

/// A frame's end-to-end CRC, in its last data bytes (little-endian).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Crc {
    /// §4: one byte
    Crc8SaeJ1850,
    /// §10.3: two bytes
    Crc16CcittFalse,
}

impl Crc {
    fn from_table(v: &Value, path: &str) -> Result<Option<Crc>, String> {
        let t = codec::field(v, "crc", path)?;
        if t.is_null() {
            return Ok(None);
        }
        let path = format!("{path}.crc");
        let crc = match codec::text(t, "algorithm", &path)? {
            "crc8_sae_j1850" => Crc::Crc8SaeJ1850,
            "crc16_ccitt_false" => Crc::Crc16CcittFalse,
            other => return Err(format!("{path}.algorithm: unknown CRC {other:?}")),
        };
        if codec::uint(t, "bytes", &path)? != crc.bytes() as u64 {
            return Err(format!(
                "{path}.bytes: {crc:?} takes {} byte(s)",
                crc.bytes()
            ));
        }
        Ok(Some(crc))
    }

    /// Size of the CRC at the end of the payload [bytes].
    pub(crate) fn bytes(self) -> usize {
        match self {
            Crc::Crc8SaeJ1850 => 1,
            Crc::Crc16CcittFalse => 2,
        }
    }

    /// The CRC of frame `id` whose payload before the CRC is `data`.
    pub(crate) fn of_frame(self, id: u32, data: &[u8]) -> u32 {
        match self {
            Crc::Crc8SaeJ1850 => frame_crc8(id, data) as u32,
            Crc::Crc16CcittFalse => frame_crc16(id, data) as u32,
        }
    }
}

// --- the receiver's errors (§8) ----------------------------------------------------------------
/// Why a frame of an LTC id was refused; `spec` indexes [`LtcBase::specs`]. Written out by
/// [`LtcBase::write_error`] with ltc_protocol.py's FrameError texts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LtcError {
    /// a bus error frame (any id)
    ErrorFrame { id: u32 },
    /// an LTC id arrived in the 29-bit format
    Extended { spec: usize, id: u32 },
    /// an LTC id arrived as a remote request
    Remote { spec: usize },
    /// `fd`: the frame arrived as CAN FD
    FdMismatch { spec: usize, fd: bool },
    /// `len`: the data bytes that arrived
    Dlc { spec: usize, len: usize },
    /// `got` the CRC in the frame, `want` the one computed over the id and data
    Crc { spec: usize, got: u32, want: u32 },
    /// a value outside its range (or a length the codec refused)
    Codec { spec: usize, error: DecodeError },
    /// signal `signal` (index) holds `value`, inside its range but no member of `which`
    UnknownEnum {
        spec: usize,
        signal: usize,
        value: i64,
        which: LtcEnum,
    },
}

/// One LTC message: its codec, its CRC, and the signals holding LTC enums (checked in order).
pub(crate) struct Spec {
    pub(crate) codec: MessageCodec,
    /// the end-to-end CRC of host frames (§4, §10.3), None for the controller's frames
    pub(crate) crc: Option<Crc>,
    /// (signal index, enum), checked after the ranges, in ltc_protocol.py's order
    pub(crate) enums: Vec<(usize, LtcEnum)>,
}

/// What both profiles share (ltc_protocol.py `LtcProtocolBase` plus the adapters' common parts).
pub(crate) struct LtcBase {
    /// "LTC-1" or "LTC-1F", as error texts name the protocol
    pub(crate) protocol: &'static str,
    /// LTC-1's wording of the FD mismatch ("CAN FD frame; LTC-1 is classic CAN")
    classic: bool,
    /// configured joints
    pub(crate) n_joints: usize,
    /// joints the DBC carries
    pub(crate) max_joints: usize,
    /// the cycle counter (Feedback.counter) wraps at this
    pub(crate) counter_modulus: u32,
    /// a command set's counter is the answered cycle's counter modulo this
    pub(crate) command_counter_modulus: u32,
    /// the controller faults when the host heartbeat is silent this long [s]
    pub(crate) host_heartbeat_timeout_s: f64,
    /// ids of the controller's per-cycle frames (a bad one loses the cycle)
    cycle_frame_ids: Vec<u32>,
    /// every LTC message of the tables, in their order
    pub(crate) specs: Vec<Spec>,
    /// standard id → index into `specs` (u8::MAX: not an LTC id)
    by_id: Vec<u8>,
    /// raw values of the frame [`LtcBase::decode`] accepted last
    pub(crate) raw: Vec<i64>,
    /// physical values for [`LtcBase::encode`], in the message's signal order
    pub(crate) values: Vec<f64>,
    /// HOST_REQUEST's message index
    request: usize,
    /// HOST_REQUEST's request, counter, crc signal indices
    request_signals: [usize; 3],
    /// wire value per HostRequest (indexed by its discriminant)
    request_values: [i64; 3],
    /// the next HOST_REQUEST's counter (§7: +1 per request frame)
    request_counter: u32,
    /// HOST_REQUEST.counter wraps at this
    request_counter_modulus: u32,
    /// HEARTBEAT_HOST, the same every time
    heartbeat: Frame,
}

impl LtcBase {
    /// Read the tables' header and messages; Err names the missing or wrong entry.
    pub(crate) fn from_tables(
        t: &Value,
        adapter: &str,
        protocol: &'static str,
        profile: &str,
    ) -> Result<LtcBase, String> {
        let p = "tables";
        let format = codec::uint(t, "format", p)?;
        if format != TABLES_FORMAT {
            return Err(format!(
                "{p}.format: {format}, this code reads format {TABLES_FORMAT}"
            ));
        }
        for (key, want) in [
            ("adapter", adapter),
            ("protocol", protocol),
            ("profile", profile),
        ] {
            let got = codec::text(t, key, p)?;
            if got != want {
                return Err(format!("{p}.{key}: {got:?}, expected {want:?}"));
            }
        }
        let max_joints = codec::uint(t, "max_joints", p)? as usize;
        if !(1..=MAX_JOINTS).contains(&max_joints) {
            return Err(format!(
                "{p}.max_joints: {max_joints} outside 1..{MAX_JOINTS}"
            ));
        }
        let n_joints = codec::uint(t, "n_joints", p)? as usize;
        if !(1..=max_joints).contains(&n_joints) {
            return Err(format!(
                "{p}.n_joints: {protocol} carries 1..{max_joints} joints, not {n_joints}"
            ));
        }
        let modulus = |key: &str| -> Result<u32, String> {
            let m = codec::uint(t, key, p)?;
            u32::try_from(m)
                .ok()
                .filter(|&m| m > 0)
                .ok_or_else(|| format!("{p}.{key}: {m} outside 1..{}", u32::MAX))
        };
        let counter_modulus = modulus("counter_modulus")?;
        let command_counter_modulus = modulus("command_counter_modulus")?;
        let request_counter_modulus = modulus("request_counter_modulus")?;
        let timeout = codec::float(t, "host_heartbeat_timeout_s", p)?;
        if !(timeout.is_finite() && timeout > 0.0) {
            return Err(format!(
                "{p}.host_heartbeat_timeout_s: {timeout} must be > 0"
            ));
        }
        let mut cycle_frame_ids = Vec::new();
        for id in codec::array(t, "cycle_frame_ids", p)? {
            let id = id
                .as_u64()
                .ok_or_else(|| format!("{p}.cycle_frame_ids: {id} is not an id"))?;
            cycle_frame_ids.push(id as u32);
        }

        let mut specs = Vec::new();
        let mut by_id = vec![u8::MAX; CAN_SFF_MASK as usize + 1];
        let mut max_signals = 0;
        for (k, m) in codec::array(t, "messages", p)?.iter().enumerate() {
            let name = m.get("name").and_then(Value::as_str).unwrap_or("?");
            let path = format!("{p}.messages[{k}: {name}]");
            let codec = MessageCodec::from_table(m, &path)?;
            if codec.extended || codec.id > CAN_SFF_MASK {
                return Err(format!("{path}: {name} must use a standard 11-bit id"));
            }
            if by_id[codec.id as usize] != u8::MAX || specs.len() >= u8::MAX as usize {
                return Err(format!(
                    "{path}.id: two LTC messages share id 0x{:03X}",
                    codec.id
                ));
            }
            let crc = Crc::from_table(m, &path)?;
            if let Some(crc) = crc {
                let k = crc.bytes();
                let at = codec.index("crc").map(|i| &codec.signals[i]);
                if at.map(|s| (s.start_bit, s.length_bits)) != Some((8 * (codec.length - k), 8 * k))
                {
                    return Err(format!(
                        "{path}: {name}.crc must be the last {k} data byte(s)"
                    ));
                }
            }
            by_id[codec.id as usize] = specs.len() as u8;
            max_signals = max_signals.max(codec.signals.len());
            specs.push(Spec {
                codec,
                crc,
                enums: Vec::new(),
            });
        }
        let mut base = LtcBase {
            protocol,
            classic: profile == "classic",
            n_joints,
            max_joints,
            counter_modulus,
            command_counter_modulus,
            host_heartbeat_timeout_s: timeout,
            cycle_frame_ids,
            specs,
            by_id,
            raw: vec![0; max_signals],
            values: vec![0.0; max_signals],
            request: 0,
            request_signals: [0; 3],
            request_values: [0; 3],
            request_counter: 0,
            request_counter_modulus,
            heartbeat: Frame::empty(0),
        };

        // HOST_REQUEST and the heartbeats (§7): the same in both profiles
        let request = base.spec("HOST_REQUEST")?;
        base.request = request;
        base.request_signals = base.signals(request, ["request", "counter", "crc"])?;
        base.require_only(request, &["request", "counter", "crc"])?;
        base.bind_enum(request, "request", LtcEnum::HostRequest)?;
        for r in [
            HostRequest::Brake,
            HostRequest::ServoOn,
            HostRequest::ResetFault,
        ] {
            base.request_values[r as usize] = LtcEnum::HostRequest.value_of(r.name()).unwrap_or(0);
        }
        for name in ["HEARTBEAT_CTRL", "HEARTBEAT_HOST"] {
            let hb = base.spec(name)?;
            base.require_only(hb, &["nmt_state"])?;
            base.bind_enum(hb, "nmt_state", LtcEnum::NmtState)?;
        }
        let nmt = codec::int(t, "heartbeat_nmt_state", p)?;
        if LtcEnum::NmtState.name_of(nmt).is_none() {
            return Err(format!(
                "{p}.heartbeat_nmt_state: {nmt} is not an NMT state"
            ));
        }
        let hb = base.spec("HEARTBEAT_HOST")?;
        base.values[0] = nmt as f64;
        base.heartbeat = base
            .encode(hb)
            .map_err(|e| format!("{p}.heartbeat_nmt_state: {e}"))?;
        // every request, with the widest counter, must encode: then the cycle never fails to
        base.request_counter = request_counter_modulus - 1;
        for r in [
            HostRequest::Brake,
            HostRequest::ServoOn,
            HostRequest::ResetFault,
        ] {
            base.fill_request(r);
            base.encode(request)
                .map_err(|e| format!("{p}.request_counter_modulus: {e}"))?;
        }
        base.request_counter = 0;
        Ok(base)
    }

    /// The index of message `name`.
    pub(crate) fn spec(&self, name: &str) -> Result<usize, String> {
        self.specs
            .iter()
            .position(|s| s.codec.name == name)
            .ok_or_else(|| format!("tables.messages: no message {name}"))
    }

    /// The indices of signals `names` of message `spec`.
    pub(crate) fn signals<const N: usize>(
        &self,
        spec: usize,
        names: [&str; N],
    ) -> Result<[usize; N], String> {
        let codec = &self.specs[spec].codec;
        let mut out = [0; N];
        for (slot, name) in out.iter_mut().zip(names) {
            *slot = codec.index(name).ok_or_else(|| {
                format!("tables.messages[{}].signals: no signal {name}", codec.name)
            })?;
        }
        Ok(out)
    }

    /// Every signal of message `spec` is one of `names` (ltc_protocol.py binds every signal by
    /// name, so it too refuses a message with signals it does not know).
    pub(crate) fn require_only(&self, spec: usize, names: &[&str]) -> Result<(), String> {
        let codec = &self.specs[spec].codec;
        match codec
            .signals
            .iter()
            .find(|s| !names.contains(&s.name.as_str()))
        {
            Some(s) => Err(format!(
                "tables.messages[{}].signals: {} is not a signal {} knows",
                codec.name, s.name, self.protocol
            )),
            None => Ok(()),
        }
    }

    /// Decode signal `name` of `spec` as `which`: the table's value names must be the enum's,
    /// and the signal an unscaled integer.
    pub(crate) fn bind_enum(
        &mut self,
        spec: usize,
        name: &str,
        which: LtcEnum,
    ) -> Result<(), String> {
        let [i] = self.signals(spec, [name])?;
        let codec = &self.specs[spec].codec;
        let sig = &codec.signals[i];
        let want: Vec<(i64, String)> = which
            .members()
            .iter()
            .map(|(v, n)| (*v, n.to_string()))
            .collect();
        if sig.choices != want {
            return Err(format!(
                "tables.messages[{}].signals[{name}].choices: {:?} differ from {} {:?}",
                codec.name,
                sig.choices,
                which.type_name(),
                which.members()
            ));
        }
        self.require_integer(spec, &[name])?;
        self.specs[spec].enums.push((i, which));
        Ok(())
    }

    /// Signals `names` of `spec` are unscaled integers (counters, flags, enums, CRCs).
    pub(crate) fn require_integer(&self, spec: usize, names: &[&str]) -> Result<(), String> {
        let codec = &self.specs[spec].codec;
        for name in names {
            let i = codec
                .index(name)
                .ok_or_else(|| format!("{}: no signal {name}", codec.name))?;
            if codec.signals[i].conversion != codec::Conversion::Identity {
                return Err(format!(
                    "tables.messages[{}].signals[{name}].conversion: {} needs an unscaled integer",
                    codec.name, self.protocol
                ));
            }
        }
        Ok(())
    }

    /// The message `id` would be, if it is an LTC message at all.
    fn lookup(&self, id: u32) -> Option<usize> {
        let i = *self.by_id.get(id as usize)?;
        (i != u8::MAX).then_some(i as usize)
    }

    /// ltc_protocol.py `LtcProtocolBase.decode`: None for an id the protocol does not define,
    /// else the message's index with its raw values in [`LtcBase::raw`]; Err for an error frame
    /// and for a frame of an LTC id that is extended, remote, of the wrong format or length, with
    /// a bad CRC, a value outside its range or an unknown enum value (§8), in ltc_protocol.py's
    /// order.
    pub(crate) fn decode(&mut self, frame: &Frame) -> Result<Option<usize>, LtcError> {
        if frame.error {
            return Err(LtcError::ErrorFrame { id: frame.id });
        }
        let Some(spec) = self.lookup(frame.id) else {
            return Ok(None);
        };
        let s = &self.specs[spec];
        let c = &s.codec;
        if frame.extended {
            return Err(LtcError::Extended { spec, id: frame.id });
        }
        if frame.remote {
            return Err(LtcError::Remote { spec });
        }
        if frame.fd != c.fd {
            return Err(LtcError::FdMismatch { spec, fd: frame.fd });
        }
        let data = frame.payload();
        if data.len() != c.length {
            return Err(LtcError::Dlc {
                spec,
                len: data.len(),
            });
        }
        if let Some(crc) = s.crc {
            let k = crc.bytes();
            let got = data[c.length - k..]
                .iter()
                .rev()
                .fold(0u32, |acc, &b| acc << 8 | b as u32);
            let want = crc.of_frame(c.id, &data[..c.length - k]);
            if got != want {
                return Err(LtcError::Crc { spec, got, want });
            }
        }
        let raw = &mut self.raw[..c.signals.len()];
        c.decode(data, raw)
            .map_err(|error| LtcError::Codec { spec, error })?;
        for &(signal, which) in &s.enums {
            if which.name_of(raw[signal]).is_none() {
                return Err(LtcError::UnknownEnum {
                    spec,
                    signal,
                    value: raw[signal],
                    which,
                });
            }
        }
        Ok(Some(spec))
    }

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

    /// True if `id` is one of the controller's per-cycle frames (ltc.py `is_cycle_frame`).
    pub(crate) fn is_cycle_frame(&self, id: u32) -> bool {
        self.cycle_frame_ids.contains(&id)
    }

    /// Message `spec` from [`LtcBase::values`] (ltc_protocol.py `_message`): encoded, its CRC
    /// filled in, as a classic or CAN FD frame.
    pub(crate) fn encode(&self, spec: usize) -> Result<Frame, FrameError> {
        let s = &self.specs[spec];
        let c = &s.codec;
        let mut data = [0u8; CANFD_MAX_DLEN];
        c.encode(&self.values[..c.signals.len()], &mut data[..c.length])?;
        if let Some(crc) = s.crc {
            let k = crc.bytes();
            let value = crc.of_frame(c.id, &data[..c.length - k]);
            for (j, b) in data[c.length - k..c.length].iter_mut().enumerate() {
                *b = (value >> (8 * j)) as u8;
            }
        }
        Ok(if c.fd {
            Frame::fd(c.id, &data[..c.length], c.brs)
        } else {
            Frame::classic(c.id, &data[..c.length])
        })
    }

    fn fill_request(&mut self, request: HostRequest) {
        let [r, counter, crc] = self.request_signals;
        self.values[r] = self.request_values[request as usize] as f64;
        self.values[counter] = self.request_counter as f64;
        self.values[crc] = 0.0;
    }

    /// HOST_REQUEST for `request` with the rolling request counter, which then advances.
    pub(crate) fn request_frames(&mut self, request: HostRequest, out: &mut Vec<Frame>) {
        self.fill_request(request);
        // Cannot fail: every request with every counter value encoded in from_tables.
        if let Ok(frame) = self.encode(self.request) {
            out.push(frame);
        }
        self.request_counter = (self.request_counter + 1) % self.request_counter_modulus;
    }

    /// HEARTBEAT_HOST with the tables' NMT state (OPERATIONAL), encoded once.
    pub(crate) fn heartbeat_frame(&self) -> Frame {
        self.heartbeat
    }
}

/// Indices of the CTRL_STATUS signals in a message (CTRL_STATUS, or the head of LTC-1F's
/// CYCLE_FB), and how they fill a [`Feedback`] (ltc.py `cycle_feedback`).
pub(crate) struct StatusSignals {
    counter: usize,
    state: usize,
    fault: usize,
    estop: usize,
    servo: usize,
    period: usize,
}

/// CTRL_STATUS's signals (ltc_protocol.py STATUS_SIGNALS).
pub(crate) const STATUS_SIGNALS: [&str; 7] = [
    "cycle_counter",
    "state",
    "fault_code",
    "missed_cycles",
    "estop_active",
    "servo_power",
    "cycle_period_us",
];

impl StatusSignals {
    /// Bind the status signals of `spec`, and its enums (state, then fault_code:
    /// ltc_protocol.py's order of checks).
    pub(crate) fn bind(base: &mut LtcBase, spec: usize) -> Result<StatusSignals, String> {
        let [counter, state, fault, _missed, estop, servo, period] =
            base.signals(spec, STATUS_SIGNALS)?;
        base.require_integer(spec, &STATUS_SIGNALS[..6])?;
        base.bind_enum(spec, "state", LtcEnum::ControllerState)?;
        base.bind_enum(spec, "fault_code", LtcEnum::FaultCode)?;
        Ok(StatusSignals {
            counter,
            state,
            fault,
            estop,
            servo,
            period,
        })
    }

    /// The status's cycle counter, from raw values `raw`.
    pub(crate) fn counter(&self, raw: &[i64]) -> i64 {
        raw[self.counter]
    }

    /// Fill `fb`'s status part from the accepted raw values `raw` of `codec`.
    pub(crate) fn fill(&self, codec: &MessageCodec, raw: &[i64], fb: &mut Feedback) {
        fb.counter = raw[self.counter] as u32;
        let state = ControllerState::from_u8(raw[self.state] as u8);
        fb.controller_state = state.unwrap_or(ControllerState::Fault); // checked: a member
        fb.fault = LtcEnum::FaultCode
            .name_of(raw[self.fault])
            .unwrap_or("NONE");
        fb.estop = raw[self.estop] != 0;
        fb.servo_power = raw[self.servo] != 0;
        // ltc.py: cycle_period_us * 1e-6, the same IEEE product
        fb.period_s = codec.physical(self.period, raw[self.period]) * 1e-6;
    }
}

// --- LTC-1 --------------------------------------------------------------------------------------
/// One joint's JOINT_FB of the cycle being assembled.
#[derive(Clone, Copy, Debug)]
struct JointSample {
    /// [rad]
    q: f64,
    /// [rad/s]
    dq: f64,
    /// [A]
    current: f64,
    /// the low byte of the cycle counter it carries
    counter: i64,
}

/// The LTC-1 host adapter (registry name `ltc_dbc`): ltc.py `LtcAdapter`.
pub struct LtcAdapter {
    base: LtcBase,
    stats: AdapterStats,
    /// CTRL_STATUS's message index and id
    status: usize,
    status_id: u32,
    status_signals: StatusSignals,
    /// JOINT_FB_Jk (k = index + 1) message indices, for every joint the DBC carries
    feedback: [usize; MAX_JOINTS],
    /// position, velocity, current, counter of each JOINT_FB
    feedback_signals: [[usize; 4]; MAX_JOINTS],
    /// the joint (1-based) of each message index that is a JOINT_FB, 0 for the others
    joint_of: Vec<u8>,
    /// JOINT_CMD_Jk (k = index + 1) message indices
    command: [usize; MAX_JOINTS],
    /// position_cmd, velocity_cmd, hold, counter, crc of each JOINT_CMD
    command_signals: [[usize; 5]; MAX_JOINTS],
    /// JOINT_FB.counter is the cycle counter modulo this (its low byte)
    feedback_counter_modulus: i64,
    /// the feedback of the cycle being assembled, per configured joint
    joints: [Option<JointSample>; MAX_JOINTS],
    /// why the cycle being assembled is already lost, if it is
    tainted: Option<LtcError>,
}

const FEEDBACK_SIGNALS: [&str; 4] = ["position", "velocity", "current", "counter"];
const COMMAND_SIGNALS: [&str; 5] = ["position_cmd", "velocity_cmd", "hold", "counter", "crc"];

impl LtcAdapter {
    /// Build from rt_tables.py's `ltc_tables("ltc_dbc", n_joints)`; Err names the missing or
    /// wrong entry.
    pub fn from_tables(tables: &Value) -> Result<LtcAdapter, String> {
        let mut base = LtcBase::from_tables(tables, "ltc_dbc", "LTC-1", "classic")?;
        let status = base.spec("CTRL_STATUS")?;
        base.require_only(status, &STATUS_SIGNALS)?;
        let status_signals = StatusSignals::bind(&mut base, status)?;
        let mut feedback = [0; MAX_JOINTS];
        let mut feedback_signals = [[0; 4]; MAX_JOINTS];
        let mut command = [0; MAX_JOINTS];
        let mut command_signals = [[0; 5]; MAX_JOINTS];
        let mut joint_of = vec![0u8; base.specs.len()];
        for k in 0..base.max_joints {
            let fb = base.spec(&format!("JOINT_FB_J{}", k + 1))?;
            base.require_only(fb, &FEEDBACK_SIGNALS)?;
            base.require_integer(fb, &["counter"])?;
            feedback[k] = fb;
            feedback_signals[k] = base.signals(fb, FEEDBACK_SIGNALS)?;
            joint_of[fb] = (k + 1) as u8;
            let cmd = base.spec(&format!("JOINT_CMD_J{}", k + 1))?;
            base.require_only(cmd, &COMMAND_SIGNALS)?;
            base.require_integer(cmd, &["hold", "counter", "crc"])?;
            command[k] = cmd;
            command_signals[k] = base.signals(cmd, COMMAND_SIGNALS)?;
        }
        let m = codec::uint(tables, "feedback_counter_modulus", "tables")?;
        if !(1..=1 << 16).contains(&m) {
            return Err(format!(
                "tables.feedback_counter_modulus: {m} outside 1..65536"
            ));
        }
        Ok(LtcAdapter {
            status_id: base.specs[status].codec.id,
            base,
            stats: AdapterStats {
                last_error: String::with_capacity(256),
                ..Default::default()
            },
            status,
            status_signals,
            feedback,
            feedback_signals,
            joint_of,
            command,
            command_signals,
            feedback_counter_modulus: m as i64,
            joints: [None; MAX_JOINTS],
            tainted: None,
        })
    }

    /// CTRL_STATUS arrived valid: the cycle it closes, if complete and untainted.
    fn close_cycle(&mut self) -> Option<Feedback> {
        let n = self.base.n_joints;
        let joints = std::mem::replace(&mut self.joints, [None; MAX_JOINTS]);
        let tainted = self.tainted.take();
        let raw = &self.base.raw;
        let counter = self.status_signals.counter(raw);
        let stats = &mut self.stats;
        if let Some(e) = tainted {
            stats.corrupt_cycles += 1;
            stats.last_error.clear();
            let _ = write!(stats.last_error, "cycle {counter} dropped: ");
            self.base.write_error(&e, &mut stats.last_error);
            return None;
        }
        let low = counter % self.feedback_counter_modulus;
        let complete = |j: &Option<JointSample>| j.is_some_and(|s| s.counter == low);
        if !joints[..n].iter().all(complete) {
            stats.incomplete_cycles += 1;
            stats.last_error.clear();
            let _ = write!(
                stats.last_error,
                "cycle {counter} dropped: no JOINT_FB with counter {low} for joint(s) ["
            );
            let missing = joints[..n].iter().enumerate().filter(|(_, j)| !complete(j));
            for (i, (k, _)) in missing.enumerate() {
                let _ = write!(
                    stats.last_error,
                    "{}{}",
                    if i > 0 { ", " } else { "" },
                    k + 1
                );
            }
            stats.last_error.push(']');
            return None;
        }
        stats.cycles += 1;
        let mut fb = Feedback::new(n);
        for (k, j) in joints[..n].iter().enumerate() {
            let j = j.expect("complete");
            (fb.q[k], fb.dq[k], fb.current[k]) = (j.q, j.dq, j.current);
        }
        self.status_signals
            .fill(&self.base.specs[self.status].codec, raw, &mut fb);
        Some(fb)
    }
}

impl Adapter for LtcAdapter {
    fn name(&self) -> &'static str {
        "ltc_dbc"
    }

    fn counter_modulus(&self) -> u32 {
        self.base.counter_modulus
    }

    fn host_heartbeat_timeout_s(&self) -> f64 {
        self.base.host_heartbeat_timeout_s
    }

    fn n_joints(&self) -> usize {
        self.base.n_joints
    }

    fn feed(&mut self, frame: &Frame, _now: f64) -> Option<Feedback> {
        self.stats.frames += 1;
        let spec = match self.base.decode(frame) {
            Ok(Some(spec)) => spec,
            Ok(None) => {
                self.stats.unknown_frames += 1;
                return None;
            }
            Err(e) => {
                self.base.count_bad(&e, &mut self.stats);
                if frame.id == self.status_id && !frame.error {
                    // the status that would close this cycle is lost: so is the cycle
                    self.joints = [None; MAX_JOINTS];
                    self.tainted = None;
                    self.stats.corrupt_cycles += 1;
                } else if frame.error || self.base.is_cycle_frame(frame.id) {
                    self.tainted = Some(e);
                }
                return None;
            }
        };
        if spec == self.status {
            return self.close_cycle();
        }
        let joint = self.joint_of[spec] as usize;
        if joint != 0 && joint <= self.base.n_joints {
            // a bigger arm's extra joints are not ours
            let [p, v, c, counter] = self.feedback_signals[joint - 1];
            let codec = &self.base.specs[self.feedback[joint - 1]].codec;
            let raw = &self.base.raw;
            self.joints[joint - 1] = Some(JointSample {
                q: codec.physical(p, raw[p]),
                dq: codec.physical(v, raw[v]),
                current: codec.physical(c, raw[c]),
                counter: raw[counter],
            });
        }
        None // heartbeats; other hosts' commands and requests
    }

    fn command_frames(
        &mut self,
        counter: u32,
        q: &[f64],
        dq: &[f64],
        hold: bool,
        out: &mut Vec<Frame>,
    ) -> Result<(), FrameError> {
        let n = self.base.n_joints;
        if q.len() != n || dq.len() != n {
            return Err(FrameError(format!(
                "JOINT_CMD set needs {n} positions and velocities, got {} and {}",
                q.len(),
                dq.len()
            )));
        }
        let low = counter % self.base.command_counter_modulus;
        let start = out.len();
        for k in 0..n {
            let [p, v, h, c, crc] = self.command_signals[k];
            let values = &mut self.base.values;
            (values[p], values[v], values[h]) = (q[k], dq[k], if hold { 1.0 } else { 0.0 });
            (values[c], values[crc]) = (low as f64, 0.0);
            match self.base.encode(self.command[k]) {
                Ok(frame) => out.push(frame),
                Err(e) => {
                    out.truncate(start);
                    return Err(e);
                }
            }
        }
        Ok(())
    }

    fn request_frames(&mut self, request: HostRequest, out: &mut Vec<Frame>) {
        self.base.request_frames(request, out);
    }

    fn heartbeat_frame(&mut self) -> Frame {
        self.base.heartbeat_frame()
    }

    fn is_cycle_frame(&self, frame: &Frame) -> bool {
        self.base.is_cycle_frame(frame.id)
    }

    fn stats(&self) -> &AdapterStats {
        &self.stats
    }
}

/// Replaying drivers/can/rt/tests/data/ltc_golden.json (rt_tables.py `--golden`): the Python
/// adapter's behaviour, frame by frame, for both profiles (used by ltc_fd_adapter.rs's tests too).
#[cfg(test)]
pub(crate) mod golden {
    use super::*;

    pub(crate) const GOLDEN: &str = include_str!("../tests/data/ltc_golden.json");

    /// The golden cases of adapter `name`, each with its tables.
    pub(crate) fn cases(name: &str) -> Vec<Value> {
        let golden: Value = serde_json::from_str(GOLDEN).expect("ltc_golden.json is JSON");
        assert_eq!(golden["format"], TABLES_FORMAT);
        let cases: Vec<Value> = golden["cases"]
            .as_array()
            .expect("cases")
            .iter()
            .filter(|c| c["adapter"] == name)
            .cloned()
            .collect();
        assert!(!cases.is_empty(), "no golden case for {name}");
        cases
    }

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    fn flag(v: &Value, key: &str) -> bool {
        v.get(key).and_then(Value::as_bool).unwrap_or(false)
    }

    fn float(v: &Value) -> f64 {
        codec::f64_of(v).unwrap_or_else(|| panic!("not a float: {v}"))
    }

    /// The frame a golden record describes (as SocketCAN would deliver it).
    pub(crate) fn frame_of(v: &Value) -> Frame {
        let data = hex(v["data"].as_str().unwrap());
        let mut f = Frame::empty(v["id"].as_u64().unwrap() as u32);
        f.data[..data.len()].copy_from_slice(&data);
        f.len = data.len() as u8;
        f.extended = flag(v, "ext");
        f.remote = flag(v, "rtr");
        f.error = flag(v, "err");
        f.fd = flag(v, "fd");
        f.brs = flag(v, "brs");
        if f.remote {
            f.len = v["dlc"].as_u64().unwrap() as u8;
        }
        f
    }

    /// `got` is exactly the frame Python sent (id, format, flags, length, every byte).
    pub(crate) fn assert_frame(got: &Frame, want: &Value, what: &str) {
        assert_eq!(
            *got,
            frame_of(want),
            "{what}: frame differs from Python's {want}"
        );
    }

    fn assert_floats(got: &[f64], want: &Value, what: &str) {
        let want: Vec<f64> = want.as_array().unwrap().iter().map(float).collect();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(got),
            bits(&want),
            "{what}: {got:?} != Python's {want:?}"
        );
    }

    fn assert_feedback(got: &Option<Feedback>, want: &Value, n: usize, what: &str) {
        match (got, want.is_null()) {
            (None, true) => {}
            (Some(fb), false) => {
                assert_eq!(fb.n, n, "{what}: n");
                assert_eq!(
                    fb.counter as u64,
                    want["counter"].as_u64().unwrap(),
                    "{what}: counter"
                );
                assert_floats(fb.q(), &want["q"], &format!("{what}: q"));
                assert_floats(fb.dq(), &want["dq"], &format!("{what}: dq"));
                assert_floats(fb.current(), &want["current"], &format!("{what}: current"));
                assert_eq!(fb.controller_state.name(), want["state"], "{what}: state");
                assert_eq!(fb.estop, want["estop"].as_bool().unwrap(), "{what}: estop");
                assert_eq!(
                    fb.servo_power,
                    want["servo_power"].as_bool().unwrap(),
                    "{what}"
                );
                assert_eq!(fb.fault, want["fault"], "{what}: fault");
                let period = float(&want["period_s"]);
                assert_eq!(fb.period_s.to_bits(), period.to_bits(), "{what}: period_s");
            }
            _ => panic!("{what}: feedback {got:?}, Python's {want}"),
        }
    }

    /// Replay one golden case against adapters built by `build` from its tables; returns the
    /// number of frames fed, command sets, and requests compared.
    pub(crate) fn replay<A: Adapter>(
        case: &Value,
        build: fn(&Value) -> Result<A, String>,
    ) -> (usize, usize, usize) {
        let n = case["n_joints"].as_u64().unwrap() as usize;
        let label = format!("{} n={n}", case["adapter"]);
        let mut a = build(&case["tables"]).expect("tables");
        assert_eq!(a.n_joints(), n);
        let mut last_error = String::new();
        let steps = case["feed"].as_array().unwrap();
        for (k, step) in steps.iter().enumerate() {
            let what = format!("{label} feed step {k} {}", step["frame"]);
            let fb = a.feed(&frame_of(&step["frame"]), 0.0);
            assert_feedback(&fb, &step["feedback"], n, &what);
            if let Some(e) = step.get("last_error") {
                last_error = e.as_str().unwrap().to_string();
            }
            let s = a.stats();
            let counts = [
                s.frames,
                s.unknown_frames,
                s.bad_frames,
                s.cycles,
                s.incomplete_cycles,
                s.corrupt_cycles,
            ];
            let want: Vec<u64> = step["stats"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_u64().unwrap())
                .collect();
            assert_eq!(counts.to_vec(), want, "{what}: stats");
            assert_eq!(s.last_error, last_error, "{what}: last_error");
        }
        let commands = case["commands"].as_array().unwrap();
        let sentinel = Frame::classic(0x7FF, &[0xAA]);
        for (k, cmd) in commands.iter().enumerate() {
            let what = format!("{label} command set {k} {cmd}");
            let floats = |key: &str| -> Vec<f64> {
                cmd[key].as_array().unwrap().iter().map(float).collect()
            };
            let (q, dq) = (floats("q"), floats("dq"));
            let hold = cmd["hold"].as_bool().unwrap();
            let mut out = vec![sentinel];
            let r = a.command_frames(
                cmd["counter"].as_u64().unwrap() as u32,
                &q,
                &dq,
                hold,
                &mut out,
            );
            match (r, cmd.get("error")) {
                (Ok(()), None) => {
                    let want = cmd["frames"].as_array().unwrap();
                    assert_eq!(out.len(), 1 + want.len(), "{what}: frame count");
                    assert_eq!(out[0], sentinel, "{what}: frames before are kept");
                    for (j, (got, want)) in out[1..].iter().zip(want).enumerate() {
                        assert_frame(got, want, &format!("{what} frame {j}"));
                    }
                }
                (Err(e), Some(want)) => {
                    assert_eq!(e.0, want.as_str().unwrap(), "{what}");
                    assert_eq!(out, vec![sentinel], "{what}: nothing appended on error");
                }
                (r, want) => panic!("{what}: {r:?}, Python: {want:?}"),
            }
        }
        let mut a = build(&case["tables"]).expect("tables");
        let requests = case["requests"].as_array().unwrap();
        let mut out = Vec::new();
        for (k, pair) in requests.iter().enumerate() {
            let request = match pair[0].as_str().unwrap() {
                "BRAKE" => HostRequest::Brake,
                "SERVO_ON" => HostRequest::ServoOn,
                "RESET_FAULT" => HostRequest::ResetFault,
                other => panic!("request {other}"),
            };
            out.clear();
            a.request_frames(request, &mut out);
            assert_eq!(out.len(), 1);
            assert_frame(&out[0], &pair[1], &format!("{label} request {k}"));
        }
        assert_frame(
            &a.heartbeat_frame(),
            &case["heartbeat"],
            &format!("{label} heartbeat"),
        );
        (steps.len(), commands.len(), requests.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tables(n: usize) -> Value {
        let mut t = golden::cases("ltc_dbc")[0]["tables"].clone();
        t["n_joints"] = n.into();
        t
    }

    fn adapter(n: usize) -> LtcAdapter {
        LtcAdapter::from_tables(&tables(n)).unwrap()
    }

    /// The controller's side: JOINT_FB_Jk and CTRL_STATUS encoded with the same codecs.
    fn feedback(
        a: &mut LtcAdapter,
        joint: usize,
        q: f64,
        dq: f64,
        cur: f64,
        counter: u32,
    ) -> Frame {
        let spec = a.base.spec(&format!("JOINT_FB_J{joint}")).unwrap();
        let [p, v, c, k] = a.base.signals(spec, FEEDBACK_SIGNALS).unwrap();
        let values = &mut a.base.values;
        (values[p], values[v], values[c], values[k]) = (q, dq, cur, (counter & 0xFF) as f64);
        a.base.encode(spec).unwrap()
    }

    fn status(a: &mut LtcAdapter, counter: u32, state: u8, fault: u8, period_us: u32) -> Frame {
        let values = [
            counter as f64,
            state as f64,
            fault as f64,
            3.0,
            1.0,
            1.0,
            period_us as f64,
        ];
        let spec = a.status;
        let idx = a.base.signals(spec, STATUS_SIGNALS).unwrap();
        for (i, v) in idx.into_iter().zip(values) {
            a.base.values[i] = v;
        }
        a.base.encode(spec).unwrap()
    }

    fn cycle(a: &mut LtcAdapter, counter: u32, n: usize) -> Vec<Frame> {
        let mut frames: Vec<Frame> = (1..=n)
            .map(|k| feedback(a, k, 0.1 * k as f64, -0.01 * k as f64, 1.5, counter))
            .collect();
        frames.push(status(a, counter, 2, 0, 4000));
        frames
    }

    fn feed_all(a: &mut LtcAdapter, frames: &[Frame]) -> Option<Feedback> {
        let mut last = None;
        for f in frames {
            last = a.feed(f, 0.0);
        }
        last
    }

    #[test]
    fn the_status_closes_a_complete_cycle() {
        let mut a = adapter(6);
        let frames = cycle(&mut a, 0x1234, 6);
        for f in &frames[..6] {
            assert!(a.feed(f, 0.0).is_none());
        }
        let fb = a.feed(&frames[6], 0.0).expect("complete");
        assert_eq!(
            (fb.counter, fb.n, fb.controller_state),
            (0x1234, 6, ControllerState::External)
        );
        assert_eq!(
            (fb.estop, fb.servo_power, fb.fault, fb.period_s),
            (true, true, "NONE", 4000.0 * 1e-6)
        );
        assert_eq!(fb.q()[2], 300000.0 * 1e-6);
        assert_eq!(fb.current(), &[1.5; 6]);
        assert_eq!((a.stats().cycles, a.stats().frames), (1, 7));
    }

    #[test]
    fn missing_or_stale_feedback_makes_an_incomplete_cycle() {
        let mut a = adapter(3);
        let frames = cycle(&mut a, 300, 3);
        assert!(feed_all(&mut a, &[frames[0], frames[3]]).is_none());
        assert_eq!(a.stats().incomplete_cycles, 1);
        assert_eq!(
            a.stats().last_error,
            "cycle 300 dropped: no JOINT_FB with counter 44 for joint(s) [2, 3]"
        );
        let stale = feedback(&mut a, 2, 0.0, 0.0, 0.0, 299);
        assert!(feed_all(&mut a, &[frames[0], stale, frames[2], frames[3]]).is_none());
        assert!(a.stats().last_error.ends_with("for joint(s) [2]"));
        // the latest frame of a joint counts; a 6-joint controller's extra joints are ignored
        let extra = feedback(&mut a, 6, 0.0, 0.0, 0.0, 1);
        assert!(feed_all(
            &mut a,
            &[stale, frames[0], frames[1], extra, frames[2], frames[3]]
        )
        .is_some());
        assert_eq!(a.stats().cycles, 1);
    }

    #[test]
    fn a_bad_cycle_frame_or_error_frame_loses_the_cycle() {
        let mut a = adapter(2);
        let frames = cycle(&mut a, 5, 2);
        let mut short = frames[1];
        short.len = 7;
        assert!(feed_all(&mut a, &[frames[0], short, frames[2]]).is_none());
        assert_eq!((a.stats().bad_frames, a.stats().corrupt_cycles), (1, 1));
        assert_eq!(
            a.stats().last_error,
            "cycle 5 dropped: JOINT_FB_J2 (0x182): DLC 7 with 7 data bytes, expected 8"
        );
        let mut err = Frame::empty(0x40);
        err.error = true;
        assert!(feed_all(&mut a, &[frames[0], err, frames[1], frames[2]]).is_none());
        assert_eq!(a.stats().corrupt_cycles, 2);
        assert!(a
            .stats()
            .last_error
            .starts_with("cycle 5 dropped: CAN error frame received (id field 0x40)"));
        // a bad frame of another joint of the DBC also counts (it is a per-cycle frame)
        let mut j5 = feedback(&mut a, 5, 0.0, 0.0, 0.0, 5);
        j5.remote = true;
        assert!(feed_all(&mut a, &[frames[0], frames[1], j5, frames[2]]).is_none());
        assert_eq!(a.stats().corrupt_cycles, 3);
        assert!(
            feed_all(&mut a, &frames).is_some(),
            "the next cycle is fine"
        );
    }

    #[test]
    fn a_bad_status_loses_its_cycle_at_once() {
        let mut a = adapter(1);
        let frames = cycle(&mut a, 7, 1);
        let mut bad = frames[1];
        bad.data[2] = 4; // state
        assert!(feed_all(&mut a, &[frames[0], bad]).is_none());
        assert_eq!(a.stats().corrupt_cycles, 1);
        assert_eq!(
            a.stats().last_error,
            "CTRL_STATUS (0x010): state = 4 outside its range [0, 3]"
        );
        // the joints' frames went with it
        assert!(a.feed(&frames[1], 0.0).is_none());
        assert_eq!(a.stats().incomplete_cycles, 1);
        let mut fd = frames[1];
        fd.fd = true;
        a.feed(&fd, 0.0);
        assert_eq!(
            a.stats().last_error,
            "CTRL_STATUS (0x010): CAN FD frame; LTC-1 is classic CAN"
        );
        let mut ext = frames[1];
        ext.extended = true;
        a.feed(&ext, 0.0);
        assert_eq!(
            a.stats().last_error,
            "CTRL_STATUS (0x010): arrived with an extended 29-bit id 0x00000010; LTC-1 uses \
             standard 11-bit ids only"
        );
        assert_eq!(a.stats().corrupt_cycles, 3);
    }

    #[test]
    fn other_frames_neither_help_nor_hurt() {
        let mut a = adapter(1);
        let frames = cycle(&mut a, 9, 1);
        let mut request = Vec::new();
        a.request_frames(HostRequest::ServoOn, &mut request);
        let mut bad_crc = request[0];
        bad_crc.data[7] ^= 1;
        let mut nmt = a.heartbeat_frame();
        nmt.data[0] = 1;
        let unknown = Frame::classic(0x123, &[1, 2]);
        let fb = feed_all(
            &mut a,
            &[frames[0], bad_crc, nmt, unknown, request[0], frames[1]],
        );
        assert!(fb.is_some());
        let s = a.stats();
        assert_eq!(
            (s.frames, s.unknown_frames, s.bad_frames, s.cycles),
            (6, 1, 2, 1)
        );
        a.feed(&bad_crc, 0.0);
        let want = format!(
            "HOST_REQUEST (0x020): CRC 0x{:02X} does not match 0x{:02X} computed over the id and \
             data bytes 0..6",
            bad_crc.data[7], request[0].data[7]
        );
        assert_eq!(a.stats().last_error, want);
        a.feed(&nmt, 0.0);
        assert_eq!(
            a.stats().last_error,
            "HEARTBEAT_HOST (0x710): nmt_state = 1 is not a known value (0 BOOT, 4 STOPPED, 5 \
             OPERATIONAL, 127 PRE_OPERATIONAL)"
        );
    }

    #[test]
    fn command_frames_carry_the_low_byte_hold_and_crc() {
        let mut a = adapter(2);
        let mut out = Vec::with_capacity(8);
        a.command_frames(0x122A, &[0.1, -0.2], &[-0.25, 0.5], false, &mut out)
            .unwrap();
        assert_eq!(out.len(), 2);
        // PROTOCOL.md §4's example frame
        assert_eq!(out[0].id, 0x201);
        assert_eq!(
            out[0].payload(),
            &[0xa0, 0x86, 0x01, 0x3c, 0xf6, 0x00, 0x2a, 0x4f]
        );
        a.command_frames(0, &[0.0, 0.0], &[0.0, 0.0], true, &mut out)
            .unwrap();
        assert_eq!(out[3].data[5], 1, "hold");
        let e = a
            .command_frames(0, &[0.0, 9.0], &[0.0, 0.0], false, &mut out)
            .unwrap_err();
        assert_eq!(
            e.0,
            "JOINT_CMD_J2 (0x202): position_cmd = 9.0 rad outside its DBC range [-8.388608, 8.388607]"
        );
        assert_eq!(out.len(), 4, "nothing appended on error");
        let e = a
            .command_frames(0, &[0.0], &[0.0, 0.0], false, &mut out)
            .unwrap_err();
        assert_eq!(
            e.0,
            "JOINT_CMD set needs 2 positions and velocities, got 1 and 2"
        );
    }

    #[test]
    fn request_counter_rolls_over_and_heartbeat_is_operational() {
        let mut a = adapter(6);
        let mut out = Vec::new();
        for _ in 0..257 {
            a.request_frames(HostRequest::ServoOn, &mut out);
        }
        assert_eq!(out[7].payload(), &[0x01, 0x07, 0, 0, 0, 0, 0, 0xd2]); // PROTOCOL.md §4
        assert_eq!((out[255].data[1], out[256].data[1]), (255, 0));
        let hb = a.heartbeat_frame();
        assert_eq!((hb.id, hb.payload()), (0x710, &[5u8][..]));
        assert_eq!(
            (a.name(), a.counter_modulus(), a.host_heartbeat_timeout_s()),
            ("ltc_dbc", 65536, 0.5)
        );
        assert!(a.is_cycle_frame(&Frame::empty(0x186)) && !a.is_cycle_frame(&Frame::empty(0x201)));
    }

    #[test]
    fn bad_tables_are_named() {
        let err = |f: &dyn Fn(&mut Value)| {
            let mut t = tables(6);
            f(&mut t);
            LtcAdapter::from_tables(&t).err().expect("refused")
        };
        assert_eq!(
            err(&|t| t["n_joints"] = 7.into()),
            "tables.n_joints: LTC-1 carries 1..6 joints, not 7"
        );
        assert_eq!(
            err(&|t| t["adapter"] = "ltc_fd".into()),
            "tables.adapter: \"ltc_fd\", expected \"ltc_dbc\""
        );
        assert_eq!(
            err(&|t| t["format"] = 2.into()),
            "tables.format: 2, this code reads format 1"
        );
        let e = err(&|t| {
            t["messages"]
                .as_array_mut()
                .unwrap()
                .retain(|m| m["name"] != "JOINT_CMD_J4");
        });
        assert_eq!(e, "tables.messages: no message JOINT_CMD_J4");
        let e = err(&|t| {
            t["messages"][0]["signals"][0]
                .as_object_mut()
                .unwrap()
                .clear()
        });
        assert_eq!(
            e,
            "tables.messages[0: HOST_REQUEST].signals[0: ?].name: missing"
        );
        let e = err(&|t| t["messages"][3]["signals"][1]["choices"][3][1] = "LIMBO".into());
        assert!(
            e.starts_with("tables.messages[CTRL_STATUS].signals[state].choices"),
            "{e}"
        );
        let e = err(&|t| {
            t.as_object_mut()
                .unwrap()
                .remove("feedback_counter_modulus")
                .map(|_| ())
                .unwrap()
        });
        assert_eq!(e, "tables.feedback_counter_modulus: missing");
    }

    #[test]
    fn scratch_and_error_buffers_are_reused() {
        // The cycle writes into buffers sized at construction: their addresses stay put over
        // good cycles, corrupt ones (last_error rewritten) and command sets.
        let mut a = adapter(6);
        let frames = cycle(&mut a, 1, 6);
        let mut err = Frame::empty(0x40);
        err.error = true;
        feed_all(&mut a, &[frames[0], err, frames[6]]);
        let buffers = |a: &LtcAdapter| {
            (
                a.base.raw.as_ptr(),
                a.base.values.as_ptr(),
                a.stats.last_error.as_ptr(),
            )
        };
        let before = buffers(&a);
        let mut out = Vec::with_capacity(6);
        for _ in 0..3 {
            assert!(feed_all(&mut a, &frames).is_some());
            assert!(feed_all(&mut a, &[frames[0], err, frames[6]]).is_none());
            out.clear();
            a.command_frames(1, &[0.0; 6], &[0.0; 6], false, &mut out)
                .unwrap();
        }
        assert_eq!(buffers(&a), before);
        assert_eq!(a.stats().corrupt_cycles, 4);
    }

    #[test]
    fn golden_vectors_from_python() {
        let mut totals = (0, 0, 0);
        for case in golden::cases("ltc_dbc") {
            let (f, c, r) = golden::replay(&case, LtcAdapter::from_tables);
            totals = (totals.0 + f, totals.1 + c, totals.2 + r);
        }
        assert!(
            totals.0 > 1000 && totals.1 > 100 && totals.2 > 500,
            "{totals:?}"
        );
    }
}

//! [`LtcBase`] is what LTC-1 shares with its CAN FD profile LTC-1F (ltc_fd_adapter.rs), as
//! ltc_protocol.py's `LtcProtocolBase`: the tables' header and messages, the receiver's checks of
//! §8 (error frame, extended id, RTR, CAN FD or not, DLC, CRC, range, enums) with
//! ltc_protocol.py's error texts, HOST_REQUEST and the heartbeats (§7), and the CRC-8 of §4.
//!
//! It is built by each profile's adapter from drivers/can/rt_tables.py's tables; the receiver's
//! error texts are written out by ltc_base/frame_errors.rs.

use serde_json::Value;

use crate::adapter::{FrameError, HostRequest, MAX_JOINTS};
use crate::codec::{self, DecodeError, MessageCodec};
use crate::frame::{Frame, CANFD_MAX_DLEN, CAN_SFF_MASK};
use crate::frame_crc::{frame_crc16, frame_crc8};
use crate::ltc_enums::LtcEnum;

mod frame_errors;

/// The table layout this code reads (rt_tables.py `TABLES_FORMAT`).
pub const TABLES_FORMAT: u64 = 1;

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

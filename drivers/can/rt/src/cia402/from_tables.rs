//! Building the CiA 402 adapter from the tables a started Python adapter made (cia402.rs): the
//! drives, their PDO layouts and units, the heartbeat watch and the state the cycle continues
//! from, each entry checked as it is read.

use serde_json::Value;

use super::pdo::Pdo;
use super::state_machine::{DriveState, CW_FAULT_RESET};
use super::table_fields::{boolean, field, float, int, positive, text, uint, values};
use super::{
    Cia402Adapter, Joint, Kind, COB_IDS, DROPPED_CAPACITY, FAULT_TEXT_CAPACITY,
    LAST_ERROR_CAPACITY, TABLES_FORMAT,
};
use crate::adapter::{AdapterStats, HostRequest, MAX_JOINTS};
use crate::frame::CAN_SFF_MASK;

/// The request named as Python's HostRequest member.
pub(super) fn request_from_name(name: &str) -> Option<HostRequest> {
    [
        HostRequest::Brake,
        HostRequest::ServoOn,
        HostRequest::ResetFault,
    ]
    .into_iter()
    .find(|r| r.name() == name)
}

/// A string with `capacity` reserved, holding `s`.
fn reserved(s: &str, capacity: usize) -> String {
    let mut out = String::with_capacity(capacity.max(s.len()));
    out.push_str(s);
    out
}

impl Cia402Adapter {
    /// The adapter of the tables drivers/can/rt_cia402_tables.py `cia402_tables` made of a started
    /// Python adapter (format in its docstring), continuing from the state they carry. Err
    /// names the first field that is missing or out of range.
    pub fn from_tables(tables: &Value) -> Result<Cia402Adapter, String> {
        let w = "tables";
        let format = text(tables, "format", w)?;
        if format != TABLES_FORMAT {
            return Err(format!(
                "{w}.format: {format:?}, expected {TABLES_FORMAT:?}"
            ));
        }
        let name = text(tables, "adapter", w)?;
        if name != "cia402" {
            return Err(format!("{w}.adapter: {name:?} is not \"cia402\""));
        }
        let node_id = |v: &Value, key: &str, what: &str| -> Result<u8, String> {
            let id = uint(v, key, what)?;
            if (1..=127).contains(&id) {
                Ok(id as u8)
            } else {
                Err(format!("{what}.{key}: {id} is not a node id in 1..127"))
            }
        };
        let host_node_id = node_id(tables, "host_node_id", w)?;
        let sync_cob_id = uint(tables, "sync_cob_id", w)?;
        if sync_cob_id > CAN_SFF_MASK as u64 {
            return Err(format!(
                "{w}.sync_cob_id: 0x{sync_cob_id:X} is not an 11-bit CAN id"
            ));
        }
        let nmt_operational = uint(tables, "nmt_operational", w)?;
        let counter_modulus = uint(tables, "counter_modulus", w)?;
        if !(1..=u32::MAX as u64).contains(&counter_modulus) {
            return Err(format!(
                "{w}.counter_modulus: {counter_modulus} not in 1..2^32-1"
            ));
        }
        let sync_count = uint(tables, "sync_count", w)?;
        if sync_count >= counter_modulus {
            return Err(format!(
                "{w}.sync_count: {sync_count} ≥ the counter modulus"
            ));
        }
        let request_name = text(tables, "request", w)?;
        let request = request_from_name(request_name)
            .ok_or_else(|| format!("{w}.request: {request_name:?} is not a HostRequest"))?;
        let mut stats = AdapterStats::default();
        if let Some(s) = tables.get("stats").filter(|s| !s.is_null()) {
            let ws = "tables.stats";
            stats.frames = uint(s, "frames", ws)?;
            stats.unknown_frames = uint(s, "unknown_frames", ws)?;
            stats.bad_frames = uint(s, "bad_frames", ws)?;
            stats.cycles = uint(s, "cycles", ws)?;
            stats.incomplete_cycles = uint(s, "incomplete_cycles", ws)?;
            stats.corrupt_cycles = uint(s, "corrupt_cycles", ws)?;
            stats.last_error = text(s, "last_error", ws)?.to_string();
        }
        stats.last_error = reserved(&stats.last_error, LAST_ERROR_CAPACITY);

        let items = field(tables, "joints", w)?
            .as_array()
            .ok_or_else(|| format!("{w}.joints: not a list"))?;
        let n = uint(tables, "n_joints", w)? as usize;
        if !(1..=MAX_JOINTS).contains(&n) || items.len() != n {
            return Err(format!(
                "{w}.n_joints: {n} with {} drives listed (1..{MAX_JOINTS})",
                items.len()
            ));
        }
        let mut joints = Vec::with_capacity(n);
        for (k, v) in items.iter().enumerate() {
            let what = format!("{w}.joints[{k}]");
            let wp = |p: &str| format!("{what}.{p}");
            let state_text = text(v, "state", &what)?;
            let state = DriveState::from_text(state_text)
                .ok_or_else(|| format!("{what}.state: {state_text:?} is not a drive state"))?;
            let nmt_state = int(v, "nmt_state", &what)?;
            if !(-1..=0x7F).contains(&nmt_state) {
                return Err(format!("{what}.nmt_state: {nmt_state} not in -1..127"));
            }
            let heartbeat_s = match v.get("heartbeat_s") {
                None | Some(Value::Null) => None,
                Some(_) => Some(float(v, "heartbeat_s", &what)?),
            };
            let emcy_code = uint(v, "emcy_code", &what)?;
            if emcy_code > 0xFFFF {
                return Err(format!("{what}.emcy_code: 0x{emcy_code:X} is not 16 bits"));
            }
            let last_target_inc = match v.get("last_target_inc") {
                None | Some(Value::Null) => None,
                Some(_) => Some(int(v, "last_target_inc", &what)?),
            };
            let joint = Joint {
                node_id: node_id(v, "node_id", &what)?,
                inc_per_rad: positive(v, "inc_per_rad", &what)?,
                amps_per_mille: float(v, "amps_per_mille", &what)?,
                rpdo1: Pdo::from_json(field(v, "rpdo1", &what)?, &wp("rpdo1"), 2)?,
                rpdo2: Pdo::from_json(field(v, "rpdo2", &what)?, &wp("rpdo2"), 1)?,
                tpdo1: Pdo::from_json(field(v, "tpdo1", &what)?, &wp("tpdo1"), 2)?,
                tpdo2: Pdo::from_json(field(v, "tpdo2", &what)?, &wp("tpdo2"), 3)?,
                state,
                nmt_state: nmt_state as i16,
                heartbeat_s,
                emcy_code: emcy_code as u16,
                last_target_inc,
                position_inc: int(v, "position_inc", &what)?,
                tp1: values(v, "tpdo1_values", &what)?,
                tp2: values(v, "tpdo2_values", &what)?,
            };
            // RPDO1 must carry every controlword, and every position the drive reports (a
            // request re-sends it as the target): then a request's frames always pack.
            let (lo, hi) = joint.rpdo1.field(0).range();
            if lo > 0 || hi < CW_FAULT_RESET as i128 {
                return Err(format!("{what}.rpdo1: its controlword cannot hold 0x80"));
            }
            let (tlo, thi) = joint.rpdo1.field(1).range();
            let (plo, phi) = joint.tpdo1.field(1).range();
            if plo < tlo || phi > thi {
                return Err(format!(
                    "{what}.rpdo1: its target cannot hold every TPDO1 position"
                ));
            }
            for target in [joint.last_target_inc, Some(joint.position_inc)]
                .into_iter()
                .flatten()
            {
                if target < tlo || target > thi {
                    return Err(format!("{what}: target {target} does not fit RPDO1"));
                }
            }
            joints.push(joint);
        }
        let mut by_cob = vec![0u16; COB_IDS];
        for (k, j) in joints.iter().enumerate() {
            for (cob, kind) in [
                (j.tpdo1.cob_id, Kind::Tpdo1),
                (j.tpdo2.cob_id, Kind::Tpdo2),
                (0x700 + j.node_id as u32, Kind::Heartbeat),
                (0x080 + j.node_id as u32, Kind::Emcy),
            ] {
                by_cob[cob as usize] = 1 + ((k as u16) << 2 | kind as u16);
            }
        }
        let producer_heartbeat_s = positive(tables, "producer_heartbeat_s", w)?;
        let late_factor = positive(tables, "heartbeat_late_factor", w)?;
        Ok(Cia402Adapter {
            joints,
            by_cob,
            host_node_id,
            sync_cob_id: sync_cob_id as u32,
            nmt_operational: nmt_operational as u8,
            counter_modulus: counter_modulus as u32,
            clock_period_s: positive(tables, "clock_period_s", w)?,
            host_heartbeat_timeout_s: positive(tables, "host_heartbeat_timeout_s", w)?,
            // as Python computes it each cycle: HEARTBEAT_LATE_FACTOR * producer_heartbeat_s
            heartbeat_limit_s: late_factor * producer_heartbeat_s,
            request,
            dropped: reserved(text(tables, "dropped", w)?, DROPPED_CAPACITY),
            disabled_at_cycle: match field(tables, "disabled_at_cycle", w)? {
                Value::Null => None,
                _ => Some(uint(tables, "disabled_at_cycle", w)?),
            },
            host_disable_cycles: uint(tables, "host_disable_cycles", w)?,
            sync_count: sync_count as u32,
            corrupt: boolean(tables, "corrupt", w)?,
            stats,
            fault_text: reserved("NONE", FAULT_TEXT_CAPACITY),
        })
    }
}

//! The CAN link of the compiled cycle: a Linux SocketCAN raw socket (`socketcan` on `can0`,
//! production) or the virtual controller's Unix `SOCK_SEQPACKET` socket (`seqpacket`, where the
//! kernel has no SocketCAN: drivers/can/seqpacket.py). Both carry exactly `struct can_frame` /
//! `struct canfd_frame`, one per read or write, so only opening differs.

use std::ffi::CString;
use std::io;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use crate::frame::{Frame, CANFD_MTU, CAN_EFF_MASK};

/// SocketCAN constants of `<linux/can.h>` and `<linux/can/raw.h>`.
const PF_CAN: libc::c_int = 29;
const CAN_RAW: libc::c_int = 1;
const SOL_CAN_RAW: libc::c_int = 100 + CAN_RAW;
const CAN_RAW_ERR_FILTER: libc::c_int = 2;
const CAN_RAW_FD_FRAMES: libc::c_int = 5;

/// Where the frames go: `[can.transport]` of the cell config.
#[derive(Clone, Debug)]
pub enum Transport {
    /// a SocketCAN interface by name (`can0`)
    SocketCan { channel: String, fd: bool },
    /// `@name` (abstract namespace) or a socket file path; wait this long for the server [s]
    Seqpacket {
        channel: String,
        fd: bool,
        connect_timeout_s: f64,
    },
}

impl Transport {
    /// From the `[can.transport]` table (JSON of it); Err names the key that is wrong.
    pub fn from_json(v: &serde_json::Value) -> Result<Transport, String> {
        let interface = v.get("interface").and_then(|x| x.as_str()).unwrap_or("");
        let channel = v
            .get("channel")
            .and_then(|x| x.as_str())
            .ok_or("[can.transport].channel: required, a string")?
            .to_string();
        let fd = v.get("fd").and_then(|x| x.as_bool()).unwrap_or(false);
        match interface {
            "socketcan" => Ok(Transport::SocketCan { channel, fd }),
            "seqpacket" => Ok(Transport::Seqpacket {
                channel,
                fd,
                connect_timeout_s: v
                    .get("connect_timeout_s")
                    .and_then(|x| x.as_f64())
                    .unwrap_or(5.0),
            }),
            other => Err(format!(
                "[can.transport].interface = {other:?}: the compiled CAN driver speaks \
                 'socketcan' (the cell) and 'seqpacket' (the virtual controller)"
            )),
        }
    }

    pub fn fd(&self) -> bool {
        match self {
            Transport::SocketCan { fd, .. } | Transport::Seqpacket { fd, .. } => *fd,
        }
    }
}

/// An open CAN socket. Reads and writes are whole frames; `Drop` closes it.
pub struct CanSocket {
    fd: libc::c_int,
    fd_frames: bool,
    /// datagrams that were not a valid frame (dropped; the first reason kept)
    malformed: AtomicU64,
    first_malformed: Mutex<String>,
}

fn last_error(what: &str) -> io::Error {
    let e = io::Error::last_os_error();
    io::Error::new(e.kind(), format!("{what}: {e}"))
}

impl CanSocket {
    pub fn open(transport: &Transport) -> io::Result<CanSocket> {
        match transport {
            Transport::SocketCan { channel, fd } => open_socketcan(channel, *fd),
            Transport::Seqpacket {
                channel,
                fd,
                connect_timeout_s,
            } => open_seqpacket(channel, *fd, *connect_timeout_s),
        }
    }

    fn wrap(fd: libc::c_int, fd_frames: bool) -> CanSocket {
        CanSocket {
            fd,
            fd_frames,
            malformed: AtomicU64::new(0),
            first_malformed: Mutex::new(String::new()),
        }
    }

    pub fn raw_fd(&self) -> libc::c_int {
        self.fd
    }

    /// Datagrams dropped for not being a valid frame, and why the first one was.
    pub fn malformed(&self) -> (u64, String) {
        let first = self
            .first_malformed
            .lock()
            .map(|s| s.clone())
            .unwrap_or_default();
        (self.malformed.load(Ordering::Relaxed), first)
    }

    /// Wait until a frame can be read or `timeout_s` passed; true if readable.
    pub fn wait_readable(&self, timeout_s: f64) -> io::Result<bool> {
        let mut pfd = libc::pollfd {
            fd: self.fd,
            events: libc::POLLIN,
            revents: 0,
        };
        let ms = (timeout_s.max(0.0) * 1e3).ceil().min(i32::MAX as f64) as libc::c_int;
        // SAFETY: one valid pollfd for the call's duration.
        let n = unsafe { libc::poll(&mut pfd, 1, ms) };
        if n < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                return Ok(false);
            }
            return Err(e);
        }
        if n > 0
            && pfd.revents & (libc::POLLHUP | libc::POLLERR) != 0
            && pfd.revents & libc::POLLIN == 0
        {
            return Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                "CAN socket closed by the peer",
            ));
        }
        Ok(n > 0)
    }

    /// One frame if one is queued now (never blocks); None if none is.
    pub fn try_recv(&self) -> io::Result<Option<Frame>> {
        let mut buf = [0u8; CANFD_MTU + 1];
        loop {
            // SAFETY: buf outlives the call; MSG_DONTWAIT never blocks.
            let n = unsafe {
                libc::recv(
                    self.fd,
                    buf.as_mut_ptr() as *mut libc::c_void,
                    buf.len(),
                    libc::MSG_DONTWAIT,
                )
            };
            if n < 0 {
                let e = io::Error::last_os_error();
                return match e.kind() {
                    io::ErrorKind::WouldBlock => Ok(None),
                    io::ErrorKind::Interrupted => continue,
                    _ => Err(e),
                };
            }
            if n == 0 {
                return Err(io::Error::new(
                    io::ErrorKind::BrokenPipe,
                    "CAN socket closed by the peer",
                ));
            }
            match Frame::from_wire(&buf[..n as usize], self.fd_frames) {
                Ok(f) => return Ok(Some(f)),
                Err(why) => {
                    if self.malformed.fetch_add(1, Ordering::Relaxed) == 0 {
                        if let Ok(mut first) = self.first_malformed.lock() {
                            *first = why;
                        }
                    }
                }
            }
        }
    }

    /// Send one frame, waiting at most `timeout_s` for room in the socket's queue.
    pub fn send(&self, frame: &Frame, timeout_s: f64) -> io::Result<()> {
        if frame.fd && !self.fd_frames {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "an FD frame on a bus opened without fd",
            ));
        }
        let mut buf = [0u8; CANFD_MTU];
        let n = frame
            .to_wire(&mut buf)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        let deadline = Instant::now() + Duration::from_secs_f64(timeout_s.max(0.0));
        loop {
            // SAFETY: buf outlives the call.
            let sent = unsafe {
                libc::send(
                    self.fd,
                    buf.as_ptr() as *const libc::c_void,
                    n,
                    libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL,
                )
            };
            if sent == n as isize {
                return Ok(());
            }
            let e = io::Error::last_os_error();
            match e.kind() {
                io::ErrorKind::Interrupted => continue,
                io::ErrorKind::WouldBlock => {
                    let left = deadline.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        return Err(io::Error::new(
                            io::ErrorKind::TimedOut,
                            "CAN send queue full",
                        ));
                    }
                    let mut pfd = libc::pollfd {
                        fd: self.fd,
                        events: libc::POLLOUT,
                        revents: 0,
                    };
                    let ms = (left.as_secs_f64() * 1e3).ceil() as libc::c_int;
                    // SAFETY: one valid pollfd.
                    unsafe { libc::poll(&mut pfd, 1, ms.max(1)) };
                }
                _ => return Err(e),
            }
        }
    }
}

impl Drop for CanSocket {
    fn drop(&mut self) {
        // SAFETY: we own the descriptor.
        unsafe { libc::close(self.fd) };
    }
}

fn open_socketcan(channel: &str, fd_frames: bool) -> io::Result<CanSocket> {
    let name = CString::new(channel)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "NUL in the channel name"))?;
    // SAFETY: plain syscalls on a descriptor we own; structures are zeroed and sized.
    unsafe {
        let index = libc::if_nametoindex(name.as_ptr());
        if index == 0 {
            return Err(last_error(&format!("no CAN interface {channel:?}")));
        }
        let fd = libc::socket(PF_CAN, libc::SOCK_RAW | libc::SOCK_CLOEXEC, CAN_RAW);
        if fd < 0 {
            return Err(last_error("socket(PF_CAN, SOCK_RAW, CAN_RAW)"));
        }
        let sock = CanSocket::wrap(fd, fd_frames);
        let all_errors: u32 = CAN_EFF_MASK; // CAN_ERR_MASK: receive every error class
        if libc::setsockopt(
            fd,
            SOL_CAN_RAW,
            CAN_RAW_ERR_FILTER,
            &all_errors as *const u32 as *const libc::c_void,
            4,
        ) < 0
        {
            return Err(last_error("setsockopt(CAN_RAW_ERR_FILTER)"));
        }
        if fd_frames {
            let on: libc::c_int = 1;
            if libc::setsockopt(
                fd,
                SOL_CAN_RAW,
                CAN_RAW_FD_FRAMES,
                &on as *const libc::c_int as *const libc::c_void,
                4,
            ) < 0
            {
                return Err(last_error(
                    "setsockopt(CAN_RAW_FD_FRAMES): no CAN FD on this interface",
                ));
            }
        }
        // struct sockaddr_can: family, ifindex, then the address union (unused for CAN_RAW)
        let mut addr = [0u8; 24];
        addr[..2].copy_from_slice(&(PF_CAN as u16).to_ne_bytes());
        addr[4..8].copy_from_slice(&(index as i32).to_ne_bytes());
        if libc::bind(
            fd,
            addr.as_ptr() as *const libc::sockaddr,
            addr.len() as libc::socklen_t,
        ) < 0
        {
            return Err(last_error(&format!("bind to {channel}")));
        }
        Ok(sock)
    }
}

fn open_seqpacket(channel: &str, fd_frames: bool, timeout_s: f64) -> io::Result<CanSocket> {
    let bytes = channel.as_bytes();
    let abstract_ns = bytes.first() == Some(&b'@');
    // SAFETY: zeroed sockaddr_un filled within its bounds.
    let mut addr: libc::sockaddr_un = unsafe { std::mem::zeroed() };
    addr.sun_family = libc::AF_UNIX as libc::sa_family_t;
    let path: Vec<u8> = if abstract_ns {
        std::iter::once(0u8)
            .chain(bytes[1..].iter().copied())
            .collect()
    } else {
        bytes.to_vec()
    };
    if path.is_empty() || path.len() > addr.sun_path.len() - 1 || bytes.contains(&0) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("seqpacket channel {channel:?}: name the socket, '@name' or a path of at most 107 bytes"),
        ));
    }
    for (k, b) in path.iter().enumerate() {
        addr.sun_path[k] = *b as libc::c_char;
    }
    let len = (std::mem::size_of::<libc::sa_family_t>() + path.len()) as libc::socklen_t;
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s.max(0.0));
    loop {
        // SAFETY: plain syscalls on a descriptor we own.
        unsafe {
            let fd = libc::socket(libc::AF_UNIX, libc::SOCK_SEQPACKET | libc::SOCK_CLOEXEC, 0);
            if fd < 0 {
                return Err(last_error("socket(AF_UNIX, SOCK_SEQPACKET)"));
            }
            let sock = CanSocket::wrap(fd, fd_frames);
            if libc::connect(
                fd,
                &addr as *const libc::sockaddr_un as *const libc::sockaddr,
                len,
            ) == 0
            {
                return Ok(sock);
            }
            let e = io::Error::last_os_error();
            drop(sock);
            if Instant::now() >= deadline {
                return Err(io::Error::new(
                    e.kind(),
                    format!(
                        "no seqpacket CAN server at {channel:?} after {timeout_s} s ({e}); is the \
                         virtual controller (leadthrough sim) running?"
                    ),
                ));
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

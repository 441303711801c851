//! The module's Modbus TCP server: one thread accepts, one thread per connection answers, all
//! native (no Python, no GIL), created by the thread that starts the server and so at its
//! scheduling priority (the simulator's loop applies `[scheduling]` before it starts the
//! module: a real module answers on its own processor, and the test machine's load must not
//! make it late).
//!
//! Framing (Modbus Messaging on TCP/IP V1.0b §3.1): a 7-byte MBAP header (transaction id,
//! protocol id 0, length of unit id and PDU, unit id), then the PDU. A length outside 2..=254
//! loses the framing: that connection is closed. Another protocol id is not Modbus: ignored.
//! Another unit id answers SERVER DEVICE FAILURE (exception 4), as the pymodbus module did.

use std::collections::HashMap;
use std::io::{self, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::{self, JoinHandle};

use super::image::Module;
use super::pdu::{self, SERVER_DEVICE_FAILURE};

const MBAP_LEN: usize = 7;
const MAX_LENGTH_FIELD: usize = 254; // unit id + the largest PDU (253 bytes)

struct Shared {
    module: Arc<Module>,
    device_id: u8,
    stopping: AtomicBool,
    /// every open connection, to shut it down on stop
    conns: Mutex<HashMap<u64, TcpStream>>,
    next_id: AtomicU64,
    handles: Mutex<Vec<JoinHandle<()>>>,
}

/// A running server; [`Server::stop`] (or drop) closes the listener and every connection and
/// joins every thread.
pub struct Server {
    shared: Arc<Shared>,
    port: u16,
    listener_fd: i32,
    acceptor: Option<JoinHandle<()>>,
}

impl Server {
    /// Listen on `host:port` (0: a free port, see [`Server::port`]) for unit `device_id`.
    pub fn start(host: &str, port: u16, device_id: u8, module: Arc<Module>) -> io::Result<Server> {
        let listener = TcpListener::bind((host, port))?;
        let port = listener.local_addr()?.port();
        let listener_fd = listener.as_raw_fd();
        let shared = Arc::new(Shared {
            module,
            device_id,
            stopping: AtomicBool::new(false),
            conns: Mutex::new(HashMap::new()),
            next_id: AtomicU64::new(0),
            handles: Mutex::new(Vec::new()),
        });
        let s = shared.clone();
        let acceptor = thread::Builder::new()
            .name("virtual-io".into())
            .spawn(move || accept(listener, s))?;
        Ok(Server {
            shared,
            port,
            listener_fd,
            acceptor: Some(acceptor),
        })
    }

    pub fn port(&self) -> u16 {
        self.port
    }

    /// Close the listener and every connection, join every thread (idempotent).
    pub fn stop(&mut self) {
        let Some(acceptor) = self.acceptor.take() else {
            return;
        };
        self.shared.stopping.store(true, Ordering::SeqCst);
        // wakes the acceptor blocked in accept(2) (EINVAL on Linux); it owns the socket
        unsafe { libc::shutdown(self.listener_fd, libc::SHUT_RDWR) };
        let _ = acceptor.join();
        for conn in lock(&self.shared.conns).values() {
            let _ = conn.shutdown(Shutdown::Both);
        }
        let handles = std::mem::take(&mut *lock(&self.shared.handles));
        for h in handles {
            let _ = h.join();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop();
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poison| poison.into_inner())
}

fn accept(listener: TcpListener, shared: Arc<Shared>) {
    for stream in listener.incoming() {
        if shared.stopping.load(Ordering::SeqCst) {
            break;
        }
        let Ok(stream) = stream else {
            continue; // a connection reset before it was accepted
        };
        let _ = stream.set_nodelay(true);
        let id = shared.next_id.fetch_add(1, Ordering::Relaxed);
        let Ok(handle) = stream.try_clone() else {
            continue;
        };
        {
            // registered under the lock stop() shuts connections down with: a connection
            // accepted as stop() began is either shut down there or refused here
            let mut conns = lock(&shared.conns);
            if shared.stopping.load(Ordering::SeqCst) {
                break;
            }
            conns.insert(id, handle);
        }
        let s = shared.clone();
        let spawned = thread::Builder::new()
            .name("virtual-io-conn".into())
            .spawn(move || {
                serve(stream, &s);
                lock(&s.conns).remove(&id);
            });
        let mut handles = lock(&shared.handles);
        handles.retain(|h| !h.is_finished()); // finished connections' threads: joined below
        match spawned {
            Ok(h) => handles.push(h),
            Err(_) => {
                lock(&shared.conns).remove(&id);
            }
        }
    }
}

/// Answer requests on `stream` until the peer closes it, the framing is lost or the server
/// stops.
fn serve(mut stream: TcpStream, shared: &Shared) {
    let mut frame = [0u8; MBAP_LEN + MAX_LENGTH_FIELD];
    let mut response = Vec::with_capacity(256);
    let mut out = Vec::with_capacity(MBAP_LEN + 256);
    loop {
        if stream.read_exact(&mut frame[..MBAP_LEN]).is_err() {
            return;
        }
        let length = u16::from_be_bytes([frame[4], frame[5]]) as usize;
        if !(2..=MAX_LENGTH_FIELD).contains(&length) {
            return; // not a frame we can find the end of
        }
        let body = &mut frame[MBAP_LEN..MBAP_LEN + length - 1];
        if stream.read_exact(body).is_err() {
            return;
        }
        if frame[2] != 0 || frame[3] != 0 {
            continue; // protocol id: not Modbus
        }
        let unit = frame[6];
        let request = &frame[MBAP_LEN..MBAP_LEN + length - 1];
        if unit == shared.device_id {
            pdu::answer(&shared.module, request, &mut response);
        } else {
            pdu::exception(request[0], SERVER_DEVICE_FAILURE, &mut response);
        }
        if response.is_empty() {
            continue;
        }
        out.clear();
        out.extend_from_slice(&frame[..4]); // transaction and protocol ids
        out.extend_from_slice(&((response.len() + 1) as u16).to_be_bytes());
        out.push(unit);
        out.extend_from_slice(&response);
        if stream.write_all(&out).is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io_module::Inputs;
    use std::time::Duration;

    fn request(stream: &mut TcpStream, tid: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
        let mut frame = tid.to_be_bytes().to_vec();
        frame.extend_from_slice(&[0, 0]);
        frame.extend_from_slice(&((pdu.len() + 1) as u16).to_be_bytes());
        frame.push(unit);
        frame.extend_from_slice(pdu);
        stream.write_all(&frame).unwrap();
        let mut head = [0u8; MBAP_LEN];
        stream.read_exact(&mut head).unwrap();
        assert_eq!(&head[..4], &frame[..4]);
        assert_eq!(head[6], unit);
        let mut body = vec![0u8; u16::from_be_bytes([head[4], head[5]]) as usize - 1];
        stream.read_exact(&mut body).unwrap();
        body
    }

    fn connect(server: &Server) -> TcpStream {
        let s = TcpStream::connect(("127.0.0.1", server.port())).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        s
    }

    #[test]
    fn answers_over_tcp_and_refuses_another_unit() {
        let module = Arc::new(Module::new(1.5, 2.0));
        module.set_inputs(Inputs {
            p2_bar: 1.5,
            ..Default::default()
        });
        let mut server = Server::start("127.0.0.1", 0, 1, module.clone()).unwrap();
        let mut a = connect(&server);
        let mut b = connect(&server);
        assert_eq!(
            request(&mut a, 7, 1, &[4, 0, 0, 0, 2]),
            [4, 4, 0x3F, 0xC0, 0, 0]
        );
        assert_eq!(
            request(&mut b, 8, 1, &[6, 0, 0, 0x03, 0xE8]),
            [6, 0, 0, 0x03, 0xE8]
        );
        assert_eq!(module.setpoints_bar(), (1.0, 2.0));
        assert_eq!(
            request(&mut a, 9, 7, &[4, 0, 0, 0, 1]),
            [0x84, SERVER_DEVICE_FAILURE]
        );
        server.stop();
        let mut buf = [0u8; 1];
        assert_eq!(
            a.read(&mut buf).unwrap_or(0),
            0,
            "a connection outlived the server"
        );
        assert!(TcpStream::connect(("127.0.0.1", server.port)).is_err());
    }

    #[test]
    fn a_frame_whose_length_cannot_be_one_closes_its_connection_only() {
        let module = Arc::new(Module::new(0.0, 0.0));
        let server = Server::start("127.0.0.1", 0, 1, module).unwrap();
        let mut bad = connect(&server);
        bad.write_all(&[0, 1, 0, 0, 0x10, 0, 1, 3]).unwrap(); // length 4096
        let mut buf = [0u8; 1];
        assert_eq!(bad.read(&mut buf).unwrap_or(0), 0);
        let mut good = connect(&server);
        assert_eq!(request(&mut good, 1, 1, &[1, 0, 0, 0, 1]), [1, 1, 0]);
    }

    #[test]
    fn many_connections_come_and_go_without_threads_piling_up() {
        let module = Arc::new(Module::new(0.0, 0.0));
        let server = Server::start("127.0.0.1", 0, 1, module).unwrap();
        for tid in 0..200 {
            let mut c = connect(&server);
            assert_eq!(request(&mut c, tid, 1, &[1, 0, 0, 0, 1]), [1, 1, 0]);
        }
        thread::sleep(Duration::from_millis(100));
        let mut c = connect(&server);
        request(&mut c, 0, 1, &[1, 0, 0, 0, 1]); // an accept reaps the finished threads
        assert!(lock(&server.shared.handles).len() <= 2);
    }
}

//! The simulated gantry controller's Modbus TCP server (GANTRY_INTERFACE.md
//! section 1) with fault injection: exception responses or silence.

use dbt_gantry::registers::COUNT;
use std::future::{ready, Ready};
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use tokio_modbus::server::tcp::{accept_tcp_connection, Server};
use tokio_modbus::{ExceptionCode, Request, Response};

/// Injected Modbus faults.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModbusFault {
    /// Answer every read with an exception (server device failure).
    Exception,
    /// Never answer (the client must time out).
    Silent,
}

/// The register file and the fault mode.
#[derive(Clone)]
pub struct GantryService {
    /// Registers 0..COUNT at `base`.
    pub registers: Arc<Mutex<[u16; COUNT]>>,
    /// Address of register 0.
    pub base: u16,
    /// Fault to inject.
    pub fault: Option<ModbusFault>,
    /// After the first read, the thickness register takes this value (0.1
    /// mm): a compression that changes during the sweep.
    pub thickness_then: Option<u16>,
}

impl tokio_modbus::server::Service for GantryService {
    type Request = Request<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = Ready<Result<Self::Response, Self::Exception>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        match self.fault {
            Some(ModbusFault::Silent) => return ready(Ok(None)),
            Some(ModbusFault::Exception) => return ready(Err(ExceptionCode::ServerDeviceFailure)),
            None => {}
        }
        ready(match req {
            Request::ReadHoldingRegisters(addr, cnt) => {
                let (lo, n) = (addr.wrapping_sub(self.base) as usize, cnt as usize);
                if addr < self.base || lo + n > COUNT {
                    Err(ExceptionCode::IllegalDataAddress)
                } else {
                    let regs = self
                        .registers
                        .lock()
                        .map(|mut r| {
                            let out = r[lo..lo + n].to_vec();
                            if let Some(t) = self.thickness_then {
                                r[2] = t;
                            }
                            out
                        })
                        .unwrap_or_default();
                    Ok(Some(Response::ReadHoldingRegisters(regs)))
                }
            }
            _ => Err(ExceptionCode::IllegalFunction),
        })
    }
}

/// Serve `service` on `addr` until the process ends.
pub async fn serve(addr: SocketAddr, service: GantryService) -> std::io::Result<()> {
    let listener = tokio::net::TcpListener::bind(addr).await?;
    let server = Server::new(listener);
    let service = Arc::new(service);
    let new_service = move |_addr| Ok(Some(Arc::clone(&service)));
    let on_connected = move |stream, socket_addr| {
        let new_service = new_service.clone();
        async move { accept_tcp_connection(stream, socket_addr, new_service) }
    };
    server
        .serve(&on_connected, |err| eprintln!("host-sim modbus: {err}"))
        .await
}

/// Serve `service` as Modbus RTU on the serial line `path` (8N1) until the
/// process ends.
pub async fn serve_rtu(path: &str, baud: u32, service: GantryService) -> std::io::Result<()> {
    let server = tokio_modbus::server::rtu::Server::new_from_path(path, baud)?;
    server.serve_forever(Arc::new(service)).await
}

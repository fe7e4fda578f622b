//! The firmware's Modbus client (GANTRY_INTERFACE.md section 1) over TCP or
//! RTU on a serial line: read the gantry controller's holding registers with
//! a timeout on every call (tokio-modbus has none of its own) and retries
//! with doubling back-off, then decode them with `dbt_gantry::registers`.

use dbt_gantry::registers::{decode, RegisterError, Registers, COUNT};
use std::net::SocketAddr;
use std::time::Duration;
use thiserror::Error;
use tokio_modbus::client::{rtu, tcp, Reader};
use tokio_modbus::Slave;

/// Where the registers are.
#[derive(Debug, Clone, PartialEq)]
pub enum Endpoint {
    /// Modbus TCP.
    Tcp(SocketAddr),
    /// Modbus RTU on a serial line (8N1).
    Rtu {
        /// Device path.
        path: String,
        /// Baud rate.
        baud: u32,
    },
}

impl std::fmt::Display for Endpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Tcp(a) => write!(f, "tcp://{a}"),
            Self::Rtu { path, baud } => write!(f, "rtu://{path}@{baud}"),
        }
    }
}

/// Modbus faults, each naming what failed.
#[derive(Debug, Error)]
pub enum ModbusError {
    /// No answer within the timeout (after all attempts).
    #[error("Modbus {addr}: no answer within {timeout_ms} ms after {attempts} attempts")]
    Timeout {
        /// Server address.
        addr: Endpoint,
        /// Per-call timeout.
        timeout_ms: u64,
        /// Attempts made.
        attempts: u32,
    },
    /// Transport failure.
    #[error("Modbus {addr}: {reason}")]
    Transport {
        /// Server address.
        addr: Endpoint,
        /// What failed.
        reason: String,
    },
    /// The server answered with a Modbus exception.
    #[error("Modbus {addr}: exception response {exception}")]
    Exception {
        /// Server address.
        addr: Endpoint,
        /// The exception.
        exception: String,
    },
    /// A register value outside its encoding.
    #[error(transparent)]
    Register(#[from] RegisterError),
}

/// How to reach the registers.
#[derive(Debug, Clone)]
pub struct ModbusLink {
    /// Server address.
    pub addr: Endpoint,
    /// Unit (slave) id.
    pub unit: u8,
    /// Address of register 0 of the map.
    pub base: u16,
    /// Timeout of each call.
    pub timeout: Duration,
    /// Attempts before giving up.
    pub attempts: u32,
    /// First back-off delay (doubled after each failure).
    pub backoff: Duration,
}

impl ModbusLink {
    /// Defaults: unit 1, base 0, 1 s timeout, 3 attempts, 100 ms back-off.
    pub fn new(addr: SocketAddr) -> Self {
        Self::with_endpoint(Endpoint::Tcp(addr))
    }

    /// The same defaults for any endpoint.
    pub fn with_endpoint(addr: Endpoint) -> Self {
        Self {
            addr,
            unit: 1,
            base: 0,
            timeout: Duration::from_secs(1),
            attempts: 3,
            backoff: Duration::from_millis(100),
        }
    }
}

async fn read_once(link: &ModbusLink) -> Result<Vec<u16>, ModbusError> {
    let addr = link.addr.clone();
    let transport = |e: &dyn std::fmt::Display| ModbusError::Transport {
        addr: addr.clone(),
        reason: e.to_string(),
    };
    let mut ctx = match &link.addr {
        Endpoint::Tcp(a) => tcp::connect_slave(*a, Slave(link.unit))
            .await
            .map_err(|e| transport(&e))?,
        Endpoint::Rtu { path, baud } => {
            let port = tokio_serial::SerialStream::open(&tokio_serial::new(path, *baud))
                .map_err(|e| transport(&format!("opening {path}: {e}")))?;
            rtu::attach_slave(port, Slave(link.unit))
        }
    };
    match ctx.read_holding_registers(link.base, COUNT as u16).await {
        Ok(Ok(words)) => Ok(words),
        Ok(Err(exc)) => Err(ModbusError::Exception {
            addr,
            exception: format!("{exc:?}"),
        }),
        Err(e) => Err(transport(&e)),
    }
}

/// Read and decode the register map (blocking; runs its own small runtime).
pub fn read_registers(link: &ModbusLink) -> Result<Registers, ModbusError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| ModbusError::Transport {
            addr: link.addr.clone(),
            reason: e.to_string(),
        })?;
    rt.block_on(async {
        let mut delay = link.backoff;
        let mut last = None;
        for attempt in 1..=link.attempts.max(1) {
            match tokio::time::timeout(link.timeout, read_once(link)).await {
                Ok(Ok(words)) => return Ok(decode(&words)?),
                // An exception is an answer: retrying will not change it.
                Ok(Err(e @ ModbusError::Exception { .. })) => return Err(e),
                Ok(Err(e)) => last = Some(e),
                Err(_) => {
                    last = Some(ModbusError::Timeout {
                        addr: link.addr.clone(),
                        timeout_ms: link.timeout.as_millis() as u64,
                        attempts: attempt,
                    })
                }
            }
            tracing::warn!(attempt, "Modbus read failed; retrying");
            if attempt < link.attempts {
                tokio::time::sleep(delay).await;
                delay *= 2;
            }
        }
        Err(last.unwrap_or(ModbusError::Timeout {
            addr: link.addr.clone(),
            timeout_ms: link.timeout.as_millis() as u64,
            attempts: link.attempts,
        }))
    })
}

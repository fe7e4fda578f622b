//! The gantry interface, version 1 (`GANTRY_INTERFACE.md` at the repository
//! root is the specification; this crate is its reference implementation):
//! * [`frame`]: the framed binary protocol of the projection stream (start
//!   marker, version, type, sequence number, length, payload, CRC-32) with a
//!   streaming decoder that resynchronises after corruption;
//! * [`registers`]: the Modbus holding-register map of the gantry controller,
//!   decoded with range checks that name the register;
//! * [`stats`]: a reception's counters (frames, CRC and length errors,
//!   resends, garbage).
//!
//! Pure: transports (serial, TCP, Modbus client) are adapters elsewhere.

pub mod assemble;
pub mod crc;
pub mod frame;
pub mod registers;
pub mod stats;

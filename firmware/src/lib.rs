//! Firmware library: checks and services shared by the daemon and the
//! diagnostics CLI. Today it holds the projector self-test; the acquisition
//! daemon (gantry I/O, reconstruction, tissue, dose, DICOM) is built on top of
//! it by the open issues listed in the README.

pub mod calibration;
pub mod config;
pub mod daemon;
pub mod link;
pub mod modbus;
pub mod pipeline;
pub mod selftest;

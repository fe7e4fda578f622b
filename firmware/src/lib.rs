//! Firmware library: the adapters and services of the gantry PC (the frame
//! link, Modbus, the daemon (its loop), its spool and status, the status page's
//! HTTP server, the configuration,
//! the projector self-test). The processing itself is `dbt_pipeline` (pure);
//! the model folder's sign-off and calibration are `dbt_model`.

pub mod assembly;
pub mod cli;
pub mod config;
pub mod daemon;
pub mod dicom_input;
pub mod link;
pub mod modbus;
pub mod selftest;
pub mod spool;
pub mod status_page;

//! The hardware-in-the-loop tests, one test binary: each file beside this
//! one is a module of it (`autotests = false` in Cargo.toml), so the
//! workspace's build links and compiles them once instead of once a file,
//! and the test harness shares both cores between every file's tests
//! instead of running the files one after another (issue #52 point 7, CI's
//! time; docs/benchmarks.md, "CI time"). One file's tests alone: `cargo
//! test -p hil-tests --test hil daemon::`. A file left out of the list
//! below fails `architecture::every_file_in_tests_is_built`.

#[path = "architecture.rs"]
mod architecture;
#[path = "cli.rs"]
mod cli;
#[path = "daemon.rs"]
mod daemon;
#[path = "dicom_input.rs"]
mod dicom_input;
#[path = "dicom_send.rs"]
mod dicom_send;
#[path = "dicom_views.rs"]
mod dicom_views;
#[path = "docs.rs"]
mod docs;
#[path = "modbus.rs"]
mod modbus;
#[path = "openrem.rs"]
mod openrem;
#[path = "orthanc.rs"]
mod orthanc;
#[path = "progress.rs"]
mod progress;
#[path = "scp.rs"]
mod scp;
#[path = "soak.rs"]
mod soak;
#[path = "status_page.rs"]
mod status_page;
#[path = "stream.rs"]
mod stream;
#[path = "vendor_dicom.rs"]
mod vendor_dicom;

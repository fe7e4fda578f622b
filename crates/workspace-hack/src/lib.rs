//! No code. This crate's dependencies give the workspace's normal builds
//! (`cargo build --workspace --bins`) the features its test builds
//! (`cargo test --workspace`) get from dev-dependencies, so that cargo
//! compiles each crate once for both (see its Cargo.toml, and the
//! `build_and_test_features_agree` test in `hil-tests/tests/architecture.rs`).

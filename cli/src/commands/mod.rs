//! The commands, one module per group; `main.rs` parses the command line and calls them.

pub mod dem;
pub mod demo;
pub mod files;
pub mod manual;
pub mod render;

//! One module per subcommand; each parses its own arguments and calls the libraries.

pub mod bench;
pub mod common;
pub mod convert;
pub mod demo;
pub mod edit;
pub mod eval;
pub mod info;
pub mod render;
pub mod scene;
pub mod train;
pub mod uot;
pub mod view;
pub mod views;

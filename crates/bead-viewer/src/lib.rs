//! The live browser viewer of bead: a local web server that runs simulations in Rust and
//! streams their state to a page over a WebSocket.
//!
//! - [`server`]: axum router, page and assets (embedded), one task per connection.
//! - [`protocol`]: the JSON messages, versioned ([`protocol::PROTOCOL_VERSION`]).
//! - [`session`]: one connection's scene and panels, independent of the network.
//! - [`panel`]: one formulation + integrator advancing in real time.
//! - [`geometry`]: view box and curves (marching squares, parametric sampling).
//! - [`scenes`]: the shipped scenes, embedded.
#![forbid(unsafe_code)]

pub mod geometry;
pub mod panel;
pub mod protocol;
pub mod scenes;
pub mod server;
pub mod session;

pub use scenes::{Catalog, NamedScene};
pub use server::{serve, serve_blocking, ServerConfig};

//! The live browser viewer of bead: a local web server that runs simulations in Rust and
//! streams their state to a page over a WebSocket.
//!
//! - [`server`]: axum router, page and assets (embedded), one task per connection (feature
//!   `server`, on by default).
//! - [`page`]: the page's files, and the static page (the session in the browser, wasm32).
//! - [`protocol`]: the JSON messages, versioned ([`protocol::PROTOCOL_VERSION`]).
//! - [`session`]: one connection's scene and panels, independent of the network.
//! - [`panel`]: one formulation + integrator advancing in real time.
//! - [`geometry`]: view box and curves (marching squares, parametric sampling).
//! - [`scenes`]: the shipped scenes, embedded.
//! - [`clock`]: wall-clock budgets, natively or from the page's clock.
#![forbid(unsafe_code)]

pub mod clock;
pub mod geometry;
pub mod page;
pub mod panel;
pub mod protocol;
pub mod scenes;
#[cfg(feature = "server")]
pub mod server;
pub mod session;

pub use scenes::{Catalog, NamedScene};
#[cfg(feature = "server")]
pub use server::{serve, serve_blocking, ServerConfig};

//! Integration tests of pointinit, as one test binary: each file here is a module, so
//! the dependencies are linked once, not once per file. One file's tests:
//! `cargo nextest run -p pointinit FILE::`.

mod common;

mod fallback;
mod onnx;
mod plates;
mod pointmaps;
mod sweep;
mod triangulate;

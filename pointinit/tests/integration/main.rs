//! Integration tests of pointinit, as one test binary: each file here is a module, so
//! the dependencies are linked once, not once per file. One file's tests:
//! `cargo nextest run -p pointinit FILE::`.

mod common;

#[global_allocator]
static ALLOC: shared_types::fuzz::PeakAlloc = shared_types::fuzz::PeakAlloc;

mod fallback;
mod fuzz_readers;
mod onnx;
mod plates;
mod pointmaps;
mod sweep;
mod triangulate;

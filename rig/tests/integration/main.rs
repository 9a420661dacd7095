//! Integration tests of rig, as one test binary: each file here is a module, so
//! the dependencies are linked once, not once per file. One file's tests:
//! `cargo nextest run -p rig FILE::`.

mod common;
mod sync_support;

#[global_allocator]
static ALLOC: shared_types::fuzz::PeakAlloc = shared_types::fuzz::PeakAlloc;

mod frames_files;
mod fuzz_readers;
mod ingest_files;
mod ingest_images;
mod ingest_record;
mod record_live;
mod sim;
mod sync_audio;
mod sync_bench;
mod sync_files;
mod video_mp4;

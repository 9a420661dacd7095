//! Fuzzed `capture.toml`: damaged copies of the shipped capture settings and of every
//! default written out (`shared_types::fuzz`) must parse or fail with an error, never
//! panic, abort or allocate what a damaged number asks for. `PROPTEST_CASES` sets the
//! number of cases.

use std::path::Path;

use pipeline::config::CaptureConfig;
use proptest::prelude::*;
use shared_types::fuzz::{self, damaged, within_budget};

fn fixture(name: &str) -> Vec<u8> {
    std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../fixtures")
            .join(name),
    )
    .unwrap()
}

fn parse(bytes: &[u8]) -> Result<(), TestCaseError> {
    let text = String::from_utf8_lossy(bytes);
    within_budget(|| CaptureConfig::parse(&text, Path::new("capture.toml")))
}

proptest! {
    #![proptest_config(fuzz::config(1))]

    #[test]
    fn demo_capture_toml(bytes in damaged(fixture("demo-capture.toml"))) {
        parse(&bytes)?;
    }

    #[test]
    fn panoptic_capture_toml(bytes in damaged(fixture("panoptic-capture.toml"))) {
        parse(&bytes)?;
    }

    #[test]
    fn every_default_written_out(
        bytes in damaged(toml::to_string(&CaptureConfig::default()).unwrap().into_bytes())
    ) {
        parse(&bytes)?;
    }
}

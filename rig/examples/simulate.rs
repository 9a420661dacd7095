//! `cargo run -p rig --example simulate -- SCENE.toml CAPTURE_DIR`: simulate a capture
//! (the `pipeline simulate` command does the same with progress bars).

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 3 {
        eprintln!("usage: simulate SCENE.toml CAPTURE_DIR");
        std::process::exit(2);
    }
    let result = rig::sim::Scene::from_file(std::path::Path::new(&args[1])).and_then(|scene| {
        rig::sim::simulate(
            &scene,
            std::path::Path::new(&args[2]),
            &shared_types::NoProgress,
        )
    });
    match result {
        Ok(summary) => println!(
            "{}",
            serde_json::to_string_pretty(&summary).unwrap_or_default()
        ),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}

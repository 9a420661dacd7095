//! `pipeline submit`, `status` and `cancel` on a real Slurm: a one-node cluster started
//! on this machine for each test ([`Cluster`]: Debian 12's Slurm 22.05, munge with its own
//! key and socket, every daemon in the foreground in a temporary folder), running the
//! tiny simulated capture's stages as jobs.
//!
//! Without Slurm (scripts/setup.sh installs `slurmctld slurmd slurm-client munge`) or
//! without root (slurmd runs the jobs) a test skips with a message, except under
//! `CI=true`, where that is a failure.

use crate::common;

use std::collections::BTreeMap;
use std::fs;
use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use pipeline::cluster::jobs::Submission;
use pipeline::manifest::Manifest;

/// A one-node Slurm cluster of this machine, torn down on drop.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
    /// munged, slurmctld, slurmd: the processes this cluster started, ended on drop.
    daemons: Vec<(&'static str, Child)>,
}

fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true" || v == "1")
}

/// Skip with a reason, or fail under CI.
fn unavailable(reason: &str) -> Option<Cluster> {
    if in_ci() {
        panic!(
            "Slurm test cluster unavailable under CI=true: {reason} (scripts/setup.sh installs slurmctld slurmd slurm-client munge)"
        );
    }
    eprintln!("skipping: {reason}");
    None
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free local port")
}

/// `NodeName=… CPUs=… RealMemory=…` of this host, as `slurmd -C` reports it.
fn host_node_config() -> Option<BTreeMap<String, String>> {
    let out = Command::new("slurmd").arg("-C").output().ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().find(|l| l.starts_with("NodeName="))?;
    Some(
        line.split_whitespace()
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect(),
    )
}

impl Cluster {
    /// Start munged, slurmctld and slurmd and wait for the node to be idle; `None` (with
    /// the reason printed) when Slurm is not installed here, outside CI.
    fn start() -> Option<Self> {
        for program in [
            "munged",
            "slurmctld",
            "slurmd",
            "sbatch",
            "squeue",
            "scontrol",
        ] {
            if Command::new("which")
                .arg(program)
                .stdout(Stdio::null())
                .status()
                .map_or(true, |s| !s.success())
            {
                return unavailable(&format!("`{program}` is not installed"));
            }
        }
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            return unavailable("slurmd must run as root to start jobs");
        }
        let Some(node) = host_node_config() else {
            return unavailable("`slurmd -C` did not describe this host");
        };
        let host = node.get("NodeName").cloned().unwrap_or_default();
        let dir = tempfile::Builder::new()
            .prefix("slurm-test")
            .tempdir()
            .unwrap();
        let root = dir.path().to_path_buf();
        // munged needs every folder above its socket to be searchable by all.
        fs::set_permissions(&root, fs::Permissions::from_mode(0o755)).unwrap();
        for sub in ["munge", "state", "spool", "log"] {
            fs::create_dir_all(root.join(sub)).unwrap();
            fs::set_permissions(root.join(sub), fs::Permissions::from_mode(0o755)).unwrap();
        }
        let key = root.join("munge/munge.key");
        let mut bytes = vec![0u8; 1024];
        fs::File::open("/dev/urandom")
            .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut bytes))
            .unwrap();
        fs::write(&key, &bytes).unwrap();
        fs::set_permissions(&key, fs::Permissions::from_mode(0o600)).unwrap();
        let socket = root.join("munge/munge.socket");
        // Fake GPUs for `--gres`: each needs a device file, or the node drains.
        for i in 0..2 {
            std::os::unix::fs::symlink("/dev/null", root.join(format!("gpu{i}"))).unwrap();
        }
        fs::write(
            root.join("gres.conf"),
            format!(
                "NodeName={host} Name=gpu File={}\nNodeName={host} Name=gpu File={}\n",
                root.join("gpu0").display(),
                root.join("gpu1").display()
            ),
        )
        .unwrap();
        let get = |k: &str, default: &str| node.get(k).cloned().unwrap_or_else(|| default.into());
        let memory: u64 = get("RealMemory", "2048").parse().unwrap_or(2048);
        let conf = root.join("slurm.conf");
        let r = root.display();
        fs::write(
            &conf,
            format!(
                "ClusterName=test\n\
                 SlurmctldHost={host}(127.0.0.1)\n\
                 SlurmctldPort={ctld}\n\
                 SlurmdPort={slurmd}\n\
                 AuthType=auth/munge\n\
                 CredType=cred/munge\n\
                 AuthInfo=socket={socket},cred_expire=10\n\
                 SlurmUser=root\n\
                 SlurmdUser=root\n\
                 StateSaveLocation={r}/state\n\
                 SlurmdSpoolDir={r}/spool\n\
                 SlurmctldPidFile={r}/slurmctld.pid\n\
                 SlurmdPidFile={r}/slurmd.pid\n\
                 SlurmctldLogFile={r}/log/slurmctld.log\n\
                 SlurmdLogFile={r}/log/slurmd.log\n\
                 ProctrackType=proctrack/linuxproc\n\
                 TaskPlugin=task/none\n\
                 SelectType=select/cons_tres\n\
                 SelectTypeParameters=CR_Core_Memory\n\
                 SchedulerParameters=batch_sched_delay=0\n\
                 DefMemPerCPU=256\n\
                 MpiDefault=none\n\
                 ReturnToService=2\n\
                 JobAcctGatherType=jobacct_gather/none\n\
                 AccountingStorageType=accounting_storage/none\n\
                 GresTypes=gpu\n\
                 NodeName={host} NodeAddr=127.0.0.1 CPUs={cpus} Boards={boards} SocketsPerBoard={sockets} \
                 CoresPerSocket={cores} ThreadsPerCore={threads} RealMemory={memory} Gres=gpu:2 State=UNKNOWN\n\
                 PartitionName=test Nodes={host} Default=YES MaxTime=INFINITE State=UP\n",
                ctld = free_port(),
                slurmd = free_port(),
                socket = socket.display(),
                cpus = get("CPUs", "1"),
                boards = get("Boards", "1"),
                sockets = get("SocketsPerBoard", "1"),
                cores = get("CoresPerSocket", "1"),
                threads = get("ThreadsPerCore", "1"),
            ),
        )
        .unwrap();
        let mut cluster = Cluster {
            dir,
            conf,
            daemons: Vec::new(),
        };
        let munge_args = [
            "--foreground".to_string(),
            format!("--key-file={}", key.display()),
            format!("--socket={}", socket.display()),
            format!("--pid-file={r}/munge/munged.pid"),
            format!("--log-file={r}/log/munged.log"),
            format!("--seed-file={r}/munge/munged.seed"),
        ];
        cluster.spawn("munged", &munge_args);
        let start = Instant::now();
        while !socket.exists() {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "munged did not start: {}",
                cluster.logs()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        cluster.spawn("slurmctld", &["-D".into(), "-i".into()]);
        cluster.spawn("slurmd", &["-D".into(), "-N".into(), host.clone()]);
        let start = Instant::now();
        loop {
            let out = cluster.command("sinfo").args(["-h", "-o", "%T"]).output();
            let state = out.map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
            if state.as_deref().is_ok_and(|s| s == "idle") {
                break;
            }
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "the node never became idle ({state:?}): {}",
                cluster.logs()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        Some(cluster)
    }

    /// Start a daemon in its own session, its output in log/NAME.out.
    fn spawn(&mut self, program: &'static str, args: &[String]) {
        let out = fs::File::create(self.dir.path().join(format!("log/{program}.out"))).unwrap();
        let mut command = Command::new(program);
        command
            .args(args)
            .env("SLURM_CONF", &self.conf)
            .stdin(Stdio::null())
            .stdout(out.try_clone().unwrap())
            .stderr(out);
        // SAFETY: setsid is async-signal-safe; the child calls nothing else before exec.
        unsafe {
            command.pre_exec(|| {
                libc::setsid();
                Ok(())
            });
        }
        let child = command
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {program}: {e}"));
        self.daemons.push((program, child));
    }

    /// A command that talks to this cluster (and reads no user cluster file).
    fn command(&self, program: impl AsRef<std::ffi::OsStr>) -> Command {
        let mut command = Command::new(program);
        command
            .env("SLURM_CONF", &self.conf)
            .env(
                pipeline::cluster::config::USER_FILE_ENV,
                self.dir.path().join("no-user-cluster.toml"),
            )
            .env_remove("CI");
        command
    }

    /// A Slurm command on this cluster, asserting success.
    fn slurm(&self, program: &str, args: &[&str]) {
        let out = self.command(program).args(args).output().unwrap();
        assert!(
            out.status.success(),
            "{program} {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }

    /// `pipeline ARGS` on this cluster.
    fn pipeline(&self, args: &[&str]) -> Output {
        self.command(env!("CARGO_BIN_EXE_pipeline"))
            .args(args)
            .output()
            .unwrap()
    }

    /// The daemons' logs, for a failure message.
    fn logs(&self) -> String {
        let mut text = String::new();
        for name in [
            "munged.out",
            "slurmctld.out",
            "slurmd.out",
            "slurmctld.log",
            "slurmd.log",
        ] {
            let log =
                fs::read_to_string(self.dir.path().join("log").join(name)).unwrap_or_default();
            let tail: Vec<&str> = log.lines().rev().take(15).collect();
            text += &format!("\n--- {name}\n");
            for line in tail.iter().rev() {
                text += line;
                text.push('\n');
            }
        }
        text
    }

    /// What `scontrol show job -o ID` says.
    fn job_record(&self, id: &str) -> String {
        let out = self
            .command("scontrol")
            .args(["show", "job", "-o", id])
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// Wait until no stage of the capture is queued or running in Slurm; the status rows.
    /// The limit only stops a hung cluster: the jobs train, and beside the other tests on
    /// a 2-core machine they take minutes.
    fn wait_for_jobs(&self, capture: &Path) -> Vec<serde_json::Value> {
        let limit = Duration::from_secs(15 * 60);
        let start = Instant::now();
        loop {
            let rows = status(self, capture);
            let busy = rows
                .iter()
                .any(|r| r["state"] == "queued" || r["state"] == "running");
            if !busy {
                return rows;
            }
            assert!(
                start.elapsed() < limit,
                "jobs still in Slurm after {limit:?}: {rows:#?}{}",
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(250));
        }
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = self
            .command("scontrol")
            .arg("shutdown")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status();
        let start = Instant::now();
        // slurmctld and slurmd end on `scontrol shutdown`; munged, and any daemon that
        // did not, is ended here: only the processes this cluster started.
        for (name, child) in self.daemons.iter_mut().rev() {
            let grace = if *name == "munged" {
                Duration::ZERO
            } else {
                Duration::from_secs(5)
            };
            loop {
                if child.try_wait().ok().flatten().is_some() {
                    break;
                }
                if start.elapsed() >= grace {
                    let _ = child.kill();
                    let _ = child.wait();
                    break;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        }
    }
}

/// `pipeline --json status CAPTURE` rows.
fn status(cluster: &Cluster, capture: &Path) -> Vec<serde_json::Value> {
    let out = cluster.pipeline(&["--json", "status", capture.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice::<serde_json::Value>(&out.stdout)
        .unwrap()
        .as_array()
        .unwrap()
        .clone()
}

fn row<'a>(rows: &'a [serde_json::Value], stage: &str) -> &'a serde_json::Value {
    rows.iter().find(|r| r["stage"] == stage).unwrap()
}

/// `pipeline submit ARGS`; its stdout and stderr, asserting success.
fn submit(cluster: &Cluster, args: &[&str]) -> String {
    let mut all = vec!["submit"];
    all.extend_from_slice(args);
    let out = cluster.pipeline(&all);
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "submit {args:?}: {text}{}",
        cluster.logs()
    );
    text
}

/// Every stage cheap (`common::CHEAP`), one CPU per job.
fn cheap() -> String {
    format!("{}[cluster]\ncpus = 1\n", common::CHEAP)
}

/// Output files that record how long a step took (they differ between any two runs).
const TIMED: &[&str] = &["init/init.json", "train/log.csv", "export/export.json"];

#[test]
fn every_stage_runs_as_a_chained_job_and_gives_what_a_local_run_gives() {
    let Some(cluster) = Cluster::start() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("take01");
    // The engine stages ask for a (fake) GPU: `[engine] backend` is auto. They run the
    // engine-only build (no FFmpeg) as a GPU node would, where scripts/test.sh built it.
    let engine_only = std::env::var("PIPELINE_ENGINE_ONLY").ok();
    let gpu_pipeline = engine_only
        .as_ref()
        .map(|p| format!("gpu_pipeline = {p:?}\n"))
        .unwrap_or_default();
    common::tiny_capture(&root, &format!("{}gpus = 1\n{gpu_pipeline}", cheap()));
    let pristine = tmp.path().join("pristine");
    common::copy_dir(&root, &pristine);

    let said = submit(&cluster, &[root.to_str().unwrap()]);
    assert!(
        said.contains("train → job") && said.contains("(1 GPU)"),
        "{said}"
    );
    let rows = cluster.wait_for_jobs(&root);
    let names = pipeline::stages::pipeline().stage_names();
    for name in &names {
        assert_eq!(row(&rows, name)["state"], "done", "{rows:#?}");
    }

    // One job per stage, each waiting for the one before; each ran after it.
    let submission = Submission::read(&root.join("work")).unwrap();
    let stages: Vec<&str> = submission.jobs.iter().map(|j| j.stage.as_str()).collect();
    assert_eq!(stages, names);
    let mut previous: Option<(&str, Manifest)> = None;
    for job in &submission.jobs {
        assert_eq!(row(&rows, &job.stage)["job"], job.job_id.as_str());
        let dir = root.join("work").join(&job.stage);
        let manifest = Manifest::read(&dir).unwrap();
        let log = dir.join(format!("slurm-{}.log", job.job_id));
        let text = fs::read_to_string(&log).unwrap_or_else(|e| panic!("{}: {e}", log.display()));
        assert!(text.contains(&format!("{}: done", job.stage)), "{text}");
        let record = cluster.job_record(&job.job_id);
        assert!(record.contains("JobState=COMPLETED"), "{record}");
        let gpu = ["train", "render", "eval"].contains(&job.stage.as_str());
        assert_eq!(record.contains("gpu:1"), gpu, "{}: {record}", job.stage);
        if let Some(engine) = &engine_only {
            let script = root
                .join("work/.cluster")
                .join(format!("{}.sbatch", job.stage));
            let script = fs::read_to_string(&script).unwrap();
            assert_eq!(
                script.contains(engine.as_str()),
                gpu,
                "{}: {script}",
                job.stage
            );
        }
        // The stages that hold every frame ask for memory sized to the capture (its
        // recordings, probed at submit); the others take the cluster's default per CPU.
        let sized = ["train", "eval"].contains(&job.stage.as_str());
        assert_eq!(
            record.contains("MinMemoryNode="),
            sized,
            "{}: {record}",
            job.stage
        );
        if let Some((before, earlier)) = &previous {
            let prev_job = submission.job_of(before).unwrap();
            assert_eq!(job.after.as_deref(), Some(prev_job.job_id.as_str()));
            let ended = earlier.started
                + chrono::Duration::milliseconds((earlier.duration_s * 1000.0) as i64);
            assert!(
                manifest.started >= ended,
                "{} started before {before} ended",
                job.stage
            );
        }
        previous = Some((job.stage.as_str(), manifest));
    }

    // The same capture run locally, at the same path, writes the same outputs.
    let submitted = tmp.path().join("submitted");
    fs::rename(&root, &submitted).unwrap();
    fs::rename(&pristine, &root).unwrap();
    let out = cluster.pipeline(&["--quiet", "run", root.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in &names {
        let local = Manifest::read(&root.join("work").join(name)).unwrap();
        let slurm = Manifest::read(&submitted.join("work").join(name)).unwrap();
        assert_eq!(
            local.outputs.keys().collect::<Vec<_>>(),
            slurm.outputs.keys().collect::<Vec<_>>(),
            "{name}"
        );
        for (file, record) in &local.outputs {
            if !TIMED.contains(&format!("{name}/{file}").as_str()) {
                assert_eq!(record.hash, slurm.outputs[file].hash, "{name}/{file}");
            }
        }
        assert_eq!(local.parameters, slurm.parameters, "{name}");
    }
}

#[test]
fn two_captures_run_side_by_side() {
    let Some(cluster) = Cluster::start() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // Each job sleeps 2 s before its stage: one after the other, the two ingests would
    // start at least 2 s apart.
    let settings = format!("{}setup = [\"sleep 2\"]\n", cheap());
    let a = common::tiny_capture(&tmp.path().join("a"), &settings);
    let b = tmp.path().join("b");
    common::copy_dir(&a, &b);
    submit(
        &cluster,
        &[a.to_str().unwrap(), b.to_str().unwrap(), "--to", "ingest"],
    );
    for capture in [&a, &b] {
        let rows = cluster.wait_for_jobs(capture);
        assert_eq!(row(&rows, "ingest")["state"], "done", "{rows:#?}");
    }
    let started = |c: &Path| Manifest::read(&c.join("work/ingest")).unwrap().started;
    let apart = (started(&a) - started(&b)).num_milliseconds().abs();
    assert!(apart < 1500, "the two captures' jobs ran {apart} ms apart");
}

#[test]
fn a_failed_stage_cancels_its_dependents_and_a_fixed_resubmit_runs_only_the_rest() {
    let Some(cluster) = Cluster::start() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // Without `method = "timestamps"` sync fails: the tiny scene has no clap or flash.
    let broken = cheap().replace("method = \"timestamps\"", "method = \"auto\"");
    let root = common::tiny_capture(&tmp.path().join("take"), &broken);
    let dir = root.to_str().unwrap();
    submit(&cluster, &[dir, "--to", "poses"]);
    let rows = cluster.wait_for_jobs(&root);
    let first = Submission::read(&root.join("work")).unwrap();
    assert_eq!(row(&rows, "ingest")["state"], "done", "{rows:#?}");
    let sync = row(&rows, "sync");
    assert_eq!(sync["state"], "failed", "{rows:#?}");
    let sync_job = first.job_of("sync").unwrap().job_id.clone();
    let details = sync["details"].to_string();
    assert!(
        details.contains(&format!("job {sync_job} FAILED"))
            && details.contains(&format!("work/sync/slurm-{sync_job}.log"))
            && details.contains("cannot synchronise"),
        "{details}"
    );
    for stage in ["frames", "poses"] {
        let r = row(&rows, stage);
        assert_eq!(r["state"], "cancelled", "{rows:#?}");
        assert!(
            r["details"]
                .to_string()
                .contains("DependencyNeverSatisfied"),
            "{r}"
        );
    }
    assert_eq!(row(&rows, "init")["state"], "missing");
    let table = cluster.pipeline(&["status", dir]);
    let table = String::from_utf8_lossy(&table.stdout);
    assert!(
        table
            .lines()
            .any(|l| l.starts_with("frames") && l.contains("cancelled")),
        "{table}"
    );

    // Fixed: only the failed stage and the stages after it are submitted again.
    let ingest_made = Manifest::read(&root.join("work/ingest")).unwrap().started;
    fs::write(root.join("capture.toml"), cheap()).unwrap();
    let said = submit(&cluster, &[dir, "--to", "poses"]);
    assert!(said.contains("up to date: ingest"), "{said}");
    let rows = cluster.wait_for_jobs(&root);
    let second = Submission::read(&root.join("work")).unwrap();
    let stages: Vec<&str> = second.jobs.iter().map(|j| j.stage.as_str()).collect();
    assert_eq!(stages, ["sync", "frames", "poses"]);
    for stage in ["ingest", "sync", "frames", "poses"] {
        assert_eq!(row(&rows, stage)["state"], "done", "{rows:#?}");
    }
    assert_eq!(
        Manifest::read(&root.join("work/ingest")).unwrap().started,
        ingest_made
    );
    // Nothing is stale up to poses: nothing is submitted.
    let said = submit(&cluster, &[dir, "--to", "poses"]);
    assert!(said.contains("up to date, nothing submitted"), "{said}");
}

#[test]
fn cancel_leaves_no_job_behind_and_a_capture_with_jobs_is_not_run_twice() {
    let Some(cluster) = Cluster::start() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let root = common::tiny_capture(
        &tmp.path().join("take"),
        &format!("{}setup = [\"sleep 60\"]\n", cheap()),
    );
    let dir = root.to_str().unwrap();
    submit(&cluster, &[dir, "--to", "frames"]);
    let submission = Submission::read(&root.join("work")).unwrap();
    let ids = submission.job_ids();
    // Wait for the first job to run.
    let start = Instant::now();
    while row(&status(&cluster, &root), "ingest")["state"] != "running" {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "{}",
            cluster.logs()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let rows = status(&cluster, &root);
    assert_eq!(row(&rows, "sync")["state"], "queued", "{rows:#?}");

    // While its jobs are in Slurm, the capture is neither run here nor submitted again.
    for args in [vec!["run", dir], vec!["submit", dir]] {
        let out = cluster.pipeline(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}");
        assert!(
            err.contains("has jobs in Slurm") && err.contains("pipeline cancel"),
            "{args:?}: {err}"
        );
    }

    let out = cluster.pipeline(&["cancel", dir]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{said}");
    for id in &ids {
        assert!(said.contains(&format!("job {id}")), "{said}");
    }
    let out = cluster
        .command("squeue")
        .args(["-h", "-t", "all", "-o", "%i|%T", "-j", &ids.join(",")])
        .output()
        .unwrap();
    let queue = String::from_utf8_lossy(&out.stdout);
    assert_eq!(queue.lines().count(), ids.len(), "{queue}");
    assert!(
        queue.lines().all(|l| l.ends_with("|CANCELLED")),
        "jobs left behind: {queue}"
    );
    let rows = status(&cluster, &root);
    for stage in ["ingest", "sync", "frames"] {
        assert_eq!(row(&rows, stage)["state"], "cancelled", "{rows:#?}");
    }
    // Nothing left: a second cancel finds no job, and a local run goes ahead.
    let out = cluster.pipeline(&["cancel", dir]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("no job of this capture"));
    let out = cluster.pipeline(&["--quiet", "run", dir, "--to", "ingest"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A clip cut into three time chunks (`[chunks]`, the settings of `train_chunks.rs`) trains
/// one job per chunk once its frames are known: the first after `init`, the other two
/// after the first (they train on its static scene), the `train` job that merges them
/// after all three, and `render`, `eval` and `export` after that. The model is the one a
/// local run trains.
#[test]
fn a_clip_in_chunks_trains_one_job_per_chunk_and_gives_the_local_model() {
    let Some(cluster) = Cluster::start() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("take02");
    let settings = "[sync]\nmethod = \"timestamps\"\n[init]\nmoments = 2\nsweep_size = 64\nsweep_max_planes = 64\n\
        [train]\niterations = 8\nbatch_size = 1\ncheckpoint_every = 4\n\
        [train.densify]\nfrom_iteration = 2\nuntil_iteration = 6\nevery = 2\nopacity_reset_every = 0\n\
        [chunks]\nseconds = 0.34\noverlap_seconds = 0.07\n\
        [render]\nframes = 2\nvideo = false\n[eval]\nheldout_per_camera = 1\n[export]\nsteps = 1\nviewer = false\n\
        [cluster]\ncpus = 1\n";
    common::tiny_capture(&root, settings);
    let out = cluster.pipeline(&["--quiet", "run", root.to_str().unwrap(), "--to", "init"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let pristine = tmp.path().join("pristine");
    common::copy_dir(&root, &pristine);

    let said = submit(&cluster, &[root.to_str().unwrap()]);
    assert!(said.contains("train → job"), "{said}");
    let rows = cluster.wait_for_jobs(&root);
    for name in ["train", "render", "eval", "export"] {
        assert_eq!(row(&rows, name)["state"], "done", "{rows:#?}");
    }
    let submission = Submission::read(&root.join("work")).unwrap();
    let jobs: Vec<(&str, Option<usize>)> = submission
        .jobs
        .iter()
        .map(|j| (j.stage.as_str(), j.chunk))
        .collect();
    assert_eq!(
        jobs,
        [
            ("train", Some(0)),
            ("train", Some(1)),
            ("train", Some(2)),
            ("train", None),
            ("render", None),
            ("eval", None),
            ("export", None),
        ]
    );
    let id = |k: usize| submission.jobs[k].job_id.clone();
    assert_eq!(submission.jobs[0].after, None);
    assert_eq!(submission.jobs[1].after, Some(id(0)));
    assert_eq!(submission.jobs[2].after, Some(id(0)));
    assert_eq!(
        submission.jobs[3].after,
        Some(format!("{}:{}:{}", id(0), id(1), id(2)))
    );
    for job in &submission.jobs {
        let record = cluster.job_record(&job.job_id);
        assert!(record.contains("JobState=COMPLETED"), "{record}");
    }
    // Each chunk's job trained its own chunk.
    let train = root.join("work/train");
    for k in 0..3 {
        assert!(train.join(format!("chunks/{k:03}/chunk.json")).is_file());
        let log = root
            .join("work/.cluster/logs")
            .join(format!("train-{}.log", id(k)));
        let text = fs::read_to_string(&log).unwrap_or_else(|e| panic!("{}: {e}", log.display()));
        assert!(text.contains(&format!("chunk {}/3", k + 1)), "{text}");
    }

    // The same capture trained locally, at the same path, gives the same model.
    let submitted = tmp.path().join("submitted");
    fs::rename(&root, &submitted).unwrap();
    fs::rename(&pristine, &root).unwrap();
    let out = cluster.pipeline(&["--quiet", "run", root.to_str().unwrap(), "--only", "train"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        fs::read(root.join("work/train/model.bin")).unwrap(),
        fs::read(submitted.join("work/train/model.bin")).unwrap()
    );
}

#[test]
fn requests_no_node_can_satisfy_are_refused_before_anything_is_queued_and_a_default_is_lowered() {
    let Some(cluster) = Cluster::start() else {
        return;
    };
    let cpus: u32 = host_node_config()
        .and_then(|c| c.get("CPUs").and_then(|v| v.parse().ok()))
        .unwrap_or(1);
    let tmp = tempfile::tempdir().unwrap();
    let root = common::tiny_capture(&tmp.path().join("take01"), common::CHEAP);
    let capture = root.to_str().unwrap();
    // Each setting no node has: an error naming it, what the nodes have, and nothing queued.
    let too_many = cpus + 62;
    for (cluster_table, words) in [
        (
            format!("[cluster]\ncpus = {too_many}\n"),
            vec![
                format!("cpus = {too_many}"),
                format!("at most {cpus}"),
                "[cluster] cpus".into(),
            ],
        ),
        (
            "[cluster]\ncpus = 1\npartition = \"nope\"\n".into(),
            vec!["\"nope\"".into(), "partitions: test".into()],
        ),
        (
            "[cluster]\ncpus = 1\nmem = \"100T\"\n".into(),
            vec!["mem = \"100T\"".into(), "[cluster] mem".into()],
        ),
        (
            "[cluster]\ncpus = 1\ngpus = 3\n[engine]\nbackend = \"auto\"\n".into(),
            vec!["3 GPU(s)".into(), "gpu:2".into()],
        ),
    ] {
        fs::write(
            root.join("capture.toml"),
            format!("{}{cluster_table}", common::CHEAP),
        )
        .unwrap();
        let out = cluster.pipeline(&["submit", capture]);
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(!out.status.success(), "{cluster_table}: {text}");
        for w in &words {
            assert!(text.contains(w.as_str()), "{w:?} not in: {text}");
        }
        assert!(text.contains("nothing submitted"), "{text}");
        assert!(
            Submission::read(&root.join("work")).is_none(),
            "a job file was written for {cluster_table}"
        );
    }
    let queue = cluster
        .command("squeue")
        .args(["-h", "-t", "all"])
        .output()
        .unwrap();
    assert_eq!(
        String::from_utf8_lossy(&queue.stdout).trim(),
        "",
        "jobs were queued"
    );

    // The default CPUs on a smaller node: lowered, said, and asked of Slurm.
    fs::write(root.join("capture.toml"), common::CHEAP).unwrap();
    let said = submit(&cluster, &[capture, "--only", "ingest"]);
    let default = pipeline::cluster::config::DEFAULT_CPUS;
    if cpus < default {
        assert!(said.contains(&format!("the jobs ask for {cpus}")), "{said}");
    } else {
        assert!(!said.contains("note:"), "{said}");
    }
    let id = Submission::read(&root.join("work"))
        .unwrap()
        .job_of("ingest")
        .unwrap()
        .job_id
        .clone();
    let record = cluster.job_record(&id);
    assert!(
        record.contains(&format!("NumCPUs={} ", cpus.min(default))),
        "{record}"
    );
    let out = cluster.pipeline(&["cancel", capture]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The highest iteration of the checkpoints in `ckpt` (`NNNNNN.bin`), 0 when none.
fn last_checkpoint(ckpt: &Path) -> u64 {
    fs::read_dir(ckpt)
        .map(|entries| {
            entries
                .filter_map(|e| {
                    let name = e.ok()?.file_name().into_string().ok()?;
                    name.strip_suffix(".bin")?.parse().ok()
                })
                .max()
                .unwrap_or(0)
        })
        .unwrap_or(0)
}

/// Poll `done` every 100 ms; the limit only stops a hung cluster.
fn wait_until(cluster: &Cluster, what: &str, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(
            start.elapsed() < Duration::from_secs(10 * 60),
            "waited 10 min for {what}{}",
            cluster.logs()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A training job warned of its time limit (Slurm's `--signal=B:USR1`, sent here with
/// `scancel --signal`) stops at a checkpoint and requeues itself; one requeued while it
/// trains (`scontrol requeue`, as after a node failure) comes back too. Each time it
/// continues from its last checkpoint, and the model is the local run's, byte for byte.
/// While it trains, a second run of the capture is refused, naming the job.
#[test]
fn a_train_job_warned_or_requeued_continues_from_its_checkpoint_to_the_local_model() {
    let Some(cluster) = Cluster::start() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("take04");
    let settings = common::CHEAP
        .replace("iterations = 10", "iterations = 150")
        .replace("checkpoint_every = 0", "checkpoint_every = 10")
        + "[cluster]\ncpus = 1\n";
    common::tiny_capture(&root, &settings);
    let capture = root.to_str().unwrap();
    let out = cluster.pipeline(&["--quiet", "run", capture, "--to", "init"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let pristine = tmp.path().join("pristine");
    common::copy_dir(&root, &pristine);

    submit(&cluster, &[capture, "--only", "train"]);
    let work = root.join("work");
    let id = Submission::read(&work)
        .unwrap()
        .job_of("train")
        .unwrap()
        .job_id
        .clone();
    // The stage trains in `work/.train.partial/` until it is done.
    let ckpt = work.join(".train.partial/ckpt");
    // Requeued, and running again (after `cred_expire`, 10 s on this cluster).
    let restarts = |n: u32| {
        let record = cluster.job_record(&id);
        record.contains(&format!("Restarts={n} ")) && record.contains("JobState=RUNNING")
    };
    // The warning, mid-training.
    wait_until(&cluster, "a first checkpoint", || {
        last_checkpoint(&ckpt) > 0
    });
    // Meanwhile a second run of the capture is refused: a plain one because the capture has
    // jobs in Slurm; one inside the submission (as another of its jobs, on another node,
    // would be) by the capture's lock, which names the training job holding it.
    let out = cluster.pipeline(&["run", capture, "--only", "train"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("has jobs in Slurm"),
        "{err}"
    );
    let token = Submission::read(&work).unwrap().token;
    let out = cluster
        .command(env!("CARGO_BIN_EXE_pipeline"))
        .env(pipeline::cluster::jobs::SUBMISSION_ENV, &token)
        .args(["run", capture, "--only", "train"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    let host = fs::read_to_string("/proc/sys/kernel/hostname").unwrap();
    assert!(
        !out.status.success()
            && err.contains("locked by another `pipeline` run")
            && err.contains(&format!("on {}, Slurm job {id}", host.trim())),
        "{err}"
    );
    cluster.slurm("scancel", &["--signal=USR1", "--batch", &id]);
    wait_until(&cluster, "the warned job to run again", || restarts(1));
    // A requeue, once it has trained further.
    let before = last_checkpoint(&ckpt);
    wait_until(&cluster, "a later checkpoint", || {
        last_checkpoint(&ckpt) > before
    });
    cluster.slurm("scontrol", &["requeue", &id]);
    wait_until(&cluster, "the requeued job to run again", || restarts(2));

    let rows = cluster.wait_for_jobs(&root);
    assert_eq!(row(&rows, "train")["state"], "done", "{rows:#?}");
    let record = cluster.job_record(&id);
    assert!(
        record.contains("JobState=COMPLETED") && record.contains("Restarts=2 "),
        "{record}"
    );
    let logs = fs::read_dir(work.join(".cluster/logs"))
        .unwrap()
        .map(|e| fs::read_to_string(e.unwrap().path()).unwrap_or_default())
        .collect::<String>();
    assert!(logs.contains("time is nearly up"), "{logs}");

    // The same capture trained locally, uninterrupted, at the same path.
    let submitted = tmp.path().join("submitted");
    fs::rename(&root, &submitted).unwrap();
    fs::rename(&pristine, &root).unwrap();
    let out = cluster.pipeline(&["--quiet", "run", capture, "--only", "train"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        fs::read(root.join("work/train/model.bin")).unwrap()
            == fs::read(submitted.join("work/train/model.bin")).unwrap(),
        "the interrupted job trained another model than the local run"
    );
}

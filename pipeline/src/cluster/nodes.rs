//! What the cluster's nodes offer (`sinfo --Node`), and whether a job's request fits one
//! of them. `pipeline submit` checks every job before it queues any, so a request no node
//! can satisfy is an error naming the setting, the value and what the nodes have, rather
//! than Slurm's "Requested partition configuration not available now" at `scontrol
//! release`. Where only a default does not fit (`cpus`), the request is lowered to what
//! the nodes have, and `submit` says so.

use super::config::{JobRequest, SetByUser};
use super::slurm::{self, SlurmError};

/// `sinfo --Node --noheader --format=…`: node, partition (`*` marks the default), CPUs,
/// memory (MB), generic resources, the partition's time limit.
const FORMAT: &str = "%N|%P|%c|%m|%G|%l";

/// One node in one partition.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    pub name: String,
    pub partition: String,
    /// The cluster's default partition.
    pub default: bool,
    pub cpus: u32,
    pub memory_mb: u64,
    /// GPUs by type (`None`: untyped `gpu:N`).
    pub gpus: Vec<(Option<String>, u32)>,
    /// The partition's time limit in minutes; `None`: unlimited.
    pub time_limit: Option<u64>,
}

impl Node {
    /// GPUs of `kind` (any type when `None`).
    fn gpus_of(&self, kind: Option<&str>) -> u32 {
        self.gpus
            .iter()
            .filter(|(t, _)| kind.is_none() || t.as_deref() == kind)
            .map(|(_, n)| n)
            .sum()
    }

    fn describe_gpus(&self) -> String {
        if self.gpus.is_empty() {
            return "no GPUs".into();
        }
        self.gpus
            .iter()
            .map(|(t, n)| match t {
                Some(t) => format!("gpu:{t}:{n}"),
                None => format!("gpu:{n}"),
            })
            .collect::<Vec<_>>()
            .join(",")
    }
}

/// The nodes `sinfo` lists.
pub fn read() -> Result<Vec<Node>, SlurmError> {
    let out = slurm::call(
        "sinfo",
        &[
            "--Node".into(),
            "--noheader".into(),
            format!("--format={FORMAT}"),
        ],
    )?;
    Ok(parse_sinfo(&out))
}

/// The lines of `sinfo --Node --noheader --format=%N|%P|%c|%m|%G|%l`; lines that do not
/// parse are left out.
pub fn parse_sinfo(stdout: &str) -> Vec<Node> {
    stdout
        .lines()
        .filter_map(|line| {
            let f: Vec<&str> = line.trim().split('|').map(str::trim).collect();
            let [name, partition, cpus, memory, gres, limit] = f.as_slice() else {
                return None;
            };
            let number = |s: &str| s.trim_end_matches('+').parse::<u64>().ok();
            Some(Node {
                name: name.to_string(),
                partition: partition.trim_end_matches('*').to_string(),
                default: partition.ends_with('*'),
                cpus: number(cpus)? as u32,
                memory_mb: number(memory)?,
                gpus: parse_gres(gres),
                time_limit: minutes(limit),
            })
        })
        .collect()
}

/// The GPUs in a gres list: `gpu:2`, `gpu:a100:4(S:0-1)`, `gpu:a100:2,gpu:v100:1`,
/// `(null)`.
fn parse_gres(text: &str) -> Vec<(Option<String>, u32)> {
    // Drop the socket bindings in parentheses (they may hold commas).
    let mut plain = String::new();
    let mut depth = 0;
    for c in text.chars() {
        match c {
            '(' => depth += 1,
            ')' => depth -= 1,
            _ if depth == 0 => plain.push(c),
            _ => {}
        }
    }
    plain
        .split(',')
        .filter_map(|entry| {
            let parts: Vec<&str> = entry.trim().split(':').collect();
            match parts.as_slice() {
                ["gpu", n] => Some((None, n.parse().ok()?)),
                ["gpu", kind, n] => Some((Some(kind.to_string()), n.parse().ok()?)),
                _ => None,
            }
        })
        .collect()
}

/// A Slurm time (`M`, `M:S`, `H:M:S`, `D-H`, `D-H:M`, `D-H:M:S`) in whole minutes, rounded
/// up; `None` for `UNLIMITED`/`infinite` or what does not parse.
pub fn minutes(text: &str) -> Option<u64> {
    let nums = |s: &str| -> Option<Vec<u64>> { s.split(':').map(|p| p.parse().ok()).collect() };
    let seconds = match text.trim().split_once('-') {
        Some((days, rest)) => {
            let d: u64 = days.parse().ok()?;
            let hms = match nums(rest)?.as_slice() {
                [h] => h * 3600,
                [h, m] => h * 3600 + m * 60,
                [h, m, s] => h * 3600 + m * 60 + s,
                _ => return None,
            };
            d * 86_400 + hms
        }
        None => match nums(text.trim())?.as_slice() {
            [m] => m * 60,
            [m, s] => m * 60 + s,
            [h, m, s] => h * 3600 + m * 60 + s,
            _ => return None,
        },
    };
    Some(seconds.div_ceil(60))
}

/// A Slurm memory size (`16G`, `4000M`, `4000`: megabytes) in megabytes.
pub fn memory_mb(text: &str) -> Option<u64> {
    let t = text.trim();
    let (digits, unit) = match t.char_indices().find(|(_, c)| !c.is_ascii_digit()) {
        Some((i, _)) => t.split_at(i),
        None => (t, "M"),
    };
    let n: u64 = digits.parse().ok()?;
    let scale = match unit.to_ascii_uppercase().as_str() {
        "K" => return Some(n.div_ceil(1024)),
        "M" | "MB" => 1,
        "G" | "GB" => 1024,
        "T" | "TB" => 1024 * 1024,
        _ => return None,
    };
    Some(n * scale)
}

/// Whether `request` (of `stage`'s job) fits a node of its partition. `Ok(Some(n))`: it
/// fits with `n` CPUs instead of the default it asked for; `Err`: what does not fit,
/// which setting to change, and what the nodes have.
pub fn check(
    stage: &str,
    request: &JobRequest,
    set: SetByUser,
    nodes: &[Node],
) -> Result<Option<u32>, String> {
    if nodes.is_empty() {
        return Ok(None);
    }
    let keys = |key: &str| format!("[cluster] {key} (or [cluster.stages.{stage}] {key})");
    let (partition, in_partition): (String, Vec<&Node>) = match &request.partition {
        Some(p) => (
            p.clone(),
            nodes.iter().filter(|n| n.partition == *p).collect(),
        ),
        None => match nodes.iter().find(|n| n.default) {
            Some(d) => (
                d.partition.clone(),
                nodes
                    .iter()
                    .filter(|n| n.partition == d.partition)
                    .collect(),
            ),
            None => ("(all)".into(), nodes.iter().collect()),
        },
    };
    if in_partition.is_empty() {
        let mut names: Vec<&str> = nodes.iter().map(|n| n.partition.as_str()).collect();
        names.dedup();
        return Err(format!(
            "job `{stage}` asks for partition {partition:?}, which this cluster does not have (its partitions: {}); set {} to one of them",
            names.join(", "),
            keys("partition").replace("[cluster] partition", "[cluster] partition / gpu_partition"),
        ));
    }
    if let Some(time) = &request.time
        && let Some(wanted) = minutes(time)
        && let Some(limit) = in_partition.iter().filter_map(|n| n.time_limit).max()
        && in_partition.iter().all(|n| n.time_limit.is_some())
        && wanted > limit
    {
        return Err(format!(
            "job `{stage}` asks for time = {time:?} ({wanted} min); partition {partition} allows at most {limit} min; set {} to at most that, or another partition",
            keys("time")
        ));
    }
    let gpu_kind = request.gpu_type.as_deref();
    let with_gpus: Vec<&Node> = in_partition
        .iter()
        .copied()
        .filter(|n| n.gpus_of(gpu_kind) >= request.gpus)
        .collect();
    if with_gpus.is_empty() {
        let have: Vec<String> = in_partition
            .iter()
            .map(|n| format!("{}: {}", n.name, n.describe_gpus()))
            .collect();
        let what = match gpu_kind {
            Some(k) => format!("{} GPU(s) of type {k:?}", request.gpus),
            None => format!("{} GPU(s)", request.gpus),
        };
        return Err(format!(
            "job `{stage}` asks for {what}; no node of partition {partition} has them ({}); set {}, [cluster] gpu_type or gpu_partition, or run the engine on the CPU ([engine] backend = \"cpu\")",
            have.join("; "),
            keys("gpus")
        ));
    }
    let most_cpus = with_gpus.iter().map(|n| n.cpus).max().unwrap_or(0);
    let mut lowered = None;
    if request.cpus > most_cpus {
        if set.cpus {
            return Err(format!(
                "job `{stage}` asks for cpus = {}; the nodes of partition {partition} have at most {most_cpus}; set {} to at most {most_cpus}",
                request.cpus,
                keys("cpus")
            ));
        }
        lowered = Some(most_cpus);
    }
    let cpus = lowered.unwrap_or(request.cpus);
    if let Some(mem) = &request.mem
        && let Some(wanted) = memory_mb(mem)
    {
        let fits = with_gpus.iter().filter(|n| n.cpus >= cpus);
        let most = fits.map(|n| n.memory_mb).max().unwrap_or(0);
        if wanted > most {
            return Err(if set.mem {
                format!(
                    "job `{stage}` asks for mem = {mem:?}; the nodes of partition {partition} have at most {most} MB; set {} to at most {most}M",
                    keys("mem")
                )
            } else {
                format!(
                    "job `{stage}` needs about {mem} for its frames and model (sized from the capture, docs/cluster.md); the nodes of partition {partition} have at most {most} MB; train in shorter time chunks ([chunks] seconds), at a smaller [frames] size, or set {} to what the nodes have",
                    keys("mem")
                )
            });
        }
    }
    Ok(lowered)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    /// Captured from Slurm 22.05 (`sinfo --Node --noheader --format=%N|%P|%c|%m|%G|%l`) on a
    /// cluster of two CPU nodes and a GPU node, plus the test cluster's own line.
    const SINFO: &str = "\
cpu01|batch*|2|7900|(null)|1-00:00:00
cpu02|batch*|2|7900|(null)|1-00:00:00
gpu01|gpu|32|515000|gpu:a100:4(S:0-1)|2-00:00:00
gpu01|long|32|515000|gpu:a100:4(S:0-1)|infinite
garbage line
";

    fn request() -> JobRequest {
        JobRequest {
            partition: None,
            account: None,
            time: None,
            cpus: 4,
            mem: None,
            gpus: 0,
            gpu_type: None,
            sbatch_args: Vec::new(),
            setup: Vec::new(),
            prefix: None,
            program: PathBuf::from("pipeline"),
        }
    }

    #[test]
    fn sinfo_lines_give_partitions_cpus_memory_gpus_and_limits() {
        let nodes = parse_sinfo(SINFO);
        assert_eq!(nodes.len(), 4);
        assert_eq!(nodes[0].partition, "batch");
        assert!(nodes[0].default && !nodes[2].default);
        assert_eq!((nodes[0].cpus, nodes[0].memory_mb), (2, 7900));
        assert_eq!(nodes[0].time_limit, Some(24 * 60));
        assert_eq!(nodes[2].gpus, vec![(Some("a100".into()), 4)]);
        assert_eq!(nodes[3].time_limit, None);
        assert_eq!(
            parse_gres("gpu:2,gpu:v100:1(S:0,1),mps:100"),
            vec![(None, 2), (Some("v100".into()), 1)]
        );
    }

    #[test]
    fn slurm_times_and_sizes_convert() {
        assert_eq!(minutes("30"), Some(30));
        assert_eq!(minutes("30:01"), Some(31));
        assert_eq!(minutes("4:00:00"), Some(240));
        assert_eq!(minutes("1-12"), Some(36 * 60));
        assert_eq!(minutes("2-00:30"), Some(48 * 60 + 30));
        assert_eq!(minutes("UNLIMITED"), None);
        assert_eq!(memory_mb("16G"), Some(16 * 1024));
        assert_eq!(memory_mb("4000"), Some(4000));
        assert_eq!(memory_mb("1T"), Some(1024 * 1024));
        assert_eq!(memory_mb("2048K"), Some(2));
        assert_eq!(memory_mb("lots"), None);
    }

    #[test]
    fn a_default_that_fits_no_node_is_lowered_and_a_setting_is_an_error() {
        let nodes = parse_sinfo(SINFO);
        // The default 4 CPUs on 2-CPU nodes: lowered to 2.
        assert_eq!(
            check("train", &request(), SetByUser::default(), &nodes),
            Ok(Some(2))
        );
        // Set by the user: an error naming the key, the value and what the nodes have.
        let set = SetByUser {
            cpus: true,
            mem: false,
        };
        let e = check("train", &request(), set, &nodes).unwrap_err();
        assert!(
            e.contains("cpus = 4") && e.contains("at most 2") && e.contains("[cluster] cpus"),
            "{e}"
        );
        // Fits: nothing to say.
        let two = JobRequest {
            cpus: 2,
            ..request()
        };
        assert_eq!(check("train", &two, set, &nodes), Ok(None));
        // On the GPU partition the 4 CPUs fit.
        let gpu = JobRequest {
            partition: Some("gpu".into()),
            gpus: 2,
            ..request()
        };
        assert_eq!(check("train", &gpu, set, &nodes), Ok(None));
    }

    #[test]
    fn partitions_gpus_memory_and_time_that_no_node_has_are_errors_naming_the_setting() {
        let nodes = parse_sinfo(SINFO);
        let set = SetByUser {
            cpus: true,
            mem: true,
        };
        let cases = [
            (
                JobRequest {
                    partition: Some("nope".into()),
                    ..request()
                },
                vec!["\"nope\"", "batch, gpu, long", "partition"],
            ),
            (
                JobRequest {
                    cpus: 2,
                    gpus: 1,
                    ..request()
                },
                vec!["1 GPU(s)", "cpu01: no GPUs", "[cluster] gpus"],
            ),
            (
                JobRequest {
                    partition: Some("gpu".into()),
                    gpus: 1,
                    gpu_type: Some("h100".into()),
                    ..request()
                },
                vec!["type \"h100\"", "gpu:a100:4", "gpu_type"],
            ),
            (
                JobRequest {
                    cpus: 2,
                    mem: Some("16G".into()),
                    ..request()
                },
                vec!["mem = \"16G\"", "7900 MB", "[cluster] mem"],
            ),
            (
                JobRequest {
                    cpus: 2,
                    time: Some("2-00:00:00".into()),
                    ..request()
                },
                vec!["2880 min", "at most 1440 min", "[cluster] time"],
            ),
        ];
        for (req, words) in cases {
            let e = check("train", &req, set, &nodes).unwrap_err();
            for w in words {
                assert!(e.contains(w), "{w:?} not in: {e}");
            }
        }
        // Memory sized by submit (not set): the message says what to change instead.
        let sized = JobRequest {
            cpus: 2,
            mem: Some("16G".into()),
            ..request()
        };
        let e = check(
            "train",
            &sized,
            SetByUser {
                cpus: true,
                mem: false,
            },
            &nodes,
        )
        .unwrap_err();
        assert!(
            e.contains("[chunks] seconds") && e.contains("7900 MB"),
            "{e}"
        );
        // An unlimited partition takes any time.
        let long = JobRequest {
            partition: Some("long".into()),
            time: Some("30-00:00:00".into()),
            ..request()
        };
        assert_eq!(check("train", &long, set, &nodes), Ok(None));
        // No nodes listed (sinfo printed nothing): nothing to check against.
        assert_eq!(check("train", &request(), set, &[]), Ok(None));
    }
}

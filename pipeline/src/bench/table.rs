//! A benchmark's results table, kept as CSV and shown as Markdown, filled one setting at a
//! time and resumable: every row is keyed by its settings (the key columns), and a
//! setting whose key is already in the CSV is not computed again. The CSV is rewritten
//! (atomically) after every new row, so an interrupted run loses at most the row it was
//! computing.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use shared_types::Progress;

/// One row: its settings (the key) and what was measured, in the table's column order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Row {
    pub key: Vec<String>,
    pub values: Vec<String>,
}

/// Rows with named key and value columns, read from and written to one CSV file.
#[derive(Clone, Debug)]
pub struct Table {
    path: PathBuf,
    key_columns: Vec<String>,
    value_columns: Vec<String>,
    rows: Vec<Row>,
}

/// What a bench wrote: its Markdown table, its CSV and how much it computed.
#[derive(Clone, Debug)]
pub struct BenchFiles {
    pub markdown: PathBuf,
    pub csv: PathBuf,
    pub summary: FillSummary,
}

/// How many settings of a grid were computed and how many were taken from the CSV.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FillSummary {
    pub computed: usize,
    pub reused: usize,
}

impl Table {
    /// The table kept in `path`: its rows when the file exists (its header must be these
    /// columns, or all the key columns and the first value columns: a table from before
    /// value columns were added at the end, whose rows get them empty), none otherwise.
    pub fn open(path: &Path, key_columns: &[&str], value_columns: &[&str]) -> anyhow::Result<Self> {
        let mut table = Table {
            path: path.to_path_buf(),
            key_columns: key_columns.iter().map(|c| c.to_string()).collect(),
            value_columns: value_columns.iter().map(|c| c.to_string()).collect(),
            rows: Vec::new(),
        };
        if !path.exists() {
            return Ok(table);
        }
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the results {}", path.display()))?;
        let mut records = parse_csv(&text)
            .with_context(|| format!("{} is not a CSV file", path.display()))?
            .into_iter();
        let header = records.next().unwrap_or_default();
        let expected: Vec<String> = table
            .key_columns
            .iter()
            .chain(&table.value_columns)
            .cloned()
            .collect();
        let k = table.key_columns.len();
        let older = header.len() > k && expected.starts_with(&header);
        if header != expected && !older {
            bail!(
                "{} has the columns [{}], not this benchmark's [{}]; move it away or delete it \
                 (its rows cannot be reused), or give another output folder",
                path.display(),
                header.join(", "),
                expected.join(", ")
            );
        }
        for (line, mut record) in records.enumerate() {
            if older && record.len() == header.len() {
                record.resize(expected.len(), String::new());
            }
            if record.len() != expected.len() {
                bail!(
                    "{}: row {} has {} fields, the header {}; fix or delete that row",
                    path.display(),
                    line + 2,
                    record.len(),
                    header.len()
                );
            }
            let (key, values) = record.split_at(k);
            table.rows.push(Row {
                key: key.to_vec(),
                values: values.to_vec(),
            });
        }
        Ok(table)
    }

    /// The CSV file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The rows, in the order they were added.
    pub fn rows(&self) -> &[Row] {
        &self.rows
    }

    /// The row with this key.
    pub fn get(&self, key: &[String]) -> Option<&Row> {
        self.rows.iter().find(|r| r.key == key)
    }

    /// Write the table as Markdown next to the CSV (`name.md` beside `name.csv`), without
    /// the `hidden` columns.
    pub fn write_markdown(
        &self,
        title: &str,
        header: &str,
        hidden: &[&str],
        summary: FillSummary,
    ) -> anyhow::Result<BenchFiles> {
        let markdown = self.path.with_extension("md");
        let text = self.markdown(title, header, hidden);
        shared_types::atomic::write_atomic(&markdown, text.as_bytes())
            .with_context(|| format!("cannot write {}", markdown.display()))?;
        Ok(BenchFiles {
            markdown,
            csv: self.path.clone(),
            summary,
        })
    }

    /// The distinct values of `column` over the rows, sorted (e.g. the machines measured on).
    pub fn distinct(&self, column: &str) -> Vec<&str> {
        let mut values: Vec<&str> = self
            .rows
            .iter()
            .filter_map(|r| self.cell(r, column))
            .collect();
        values.sort_unstable();
        values.dedup();
        values
    }

    /// The value of `column` in `row` (key or value column).
    pub fn cell<'a>(&self, row: &'a Row, column: &str) -> Option<&'a str> {
        if let Some(i) = self.key_columns.iter().position(|c| c == column) {
            return row.key.get(i).map(String::as_str);
        }
        let i = self.value_columns.iter().position(|c| c == column)?;
        row.values.get(i).map(String::as_str)
    }

    /// Add a row, replacing one with the same key.
    pub fn insert(&mut self, row: Row) -> anyhow::Result<()> {
        if row.key.len() != self.key_columns.len() || row.values.len() != self.value_columns.len() {
            bail!(
                "a row of {} has {} key and {} value fields, the table {} and {}",
                self.path.display(),
                row.key.len(),
                row.values.len(),
                self.key_columns.len(),
                self.value_columns.len()
            );
        }
        match self.rows.iter_mut().find(|r| r.key == row.key) {
            Some(old) => *old = row,
            None => self.rows.push(row),
        }
        Ok(())
    }

    /// Compute the value columns of every key of `grid` not yet in the table, in order,
    /// writing the CSV after each; `progress` advances once per key (its message is the
    /// key being computed). Afterwards the rows are in grid order, rows of keys outside
    /// the grid (from other runs) after them.
    pub fn fill<S>(
        &mut self,
        grid: &[S],
        key: impl Fn(&S) -> Vec<String>,
        mut compute: impl FnMut(&S) -> anyhow::Result<Vec<String>>,
        progress: &dyn Progress,
    ) -> anyhow::Result<FillSummary> {
        let mut summary = FillSummary::default();
        progress.start(grid.len() as u64, "settings");
        for setting in grid {
            let key = key(setting);
            if self.get(&key).is_some() {
                summary.reused += 1;
            } else {
                progress.message(&key.join(", "));
                let values = compute(setting)?;
                self.insert(Row { key, values })?;
                self.write_csv()?;
                summary.computed += 1;
            }
            progress.advance(1);
        }
        progress.finish();
        let keys: Vec<Vec<String>> = grid.iter().map(&key).collect();
        let order = |r: &Row| keys.iter().position(|k| *k == r.key).unwrap_or(keys.len());
        if !self.rows.is_sorted_by_key(order) {
            self.rows.sort_by_key(order);
            self.write_csv()?;
        }
        Ok(summary)
    }

    /// The whole table as CSV (header first, fields quoted where needed).
    pub fn to_csv(&self) -> String {
        let mut s = String::new();
        let header: Vec<&String> = self.key_columns.iter().chain(&self.value_columns).collect();
        push_record(&mut s, header.into_iter());
        for row in &self.rows {
            push_record(&mut s, row.key.iter().chain(&row.values));
        }
        s
    }

    /// Write the CSV (to a temporary name, then renamed).
    pub fn write_csv(&self) -> anyhow::Result<()> {
        shared_types::atomic::write_atomic(&self.path, self.to_csv().as_bytes())
            .with_context(|| format!("cannot write {}", self.path.display()))
    }

    /// A Markdown document: `# title`, the `header` paragraph, then the table without the
    /// columns named in `hidden`.
    pub fn markdown(&self, title: &str, header: &str, hidden: &[&str]) -> String {
        let columns: Vec<(usize, &String)> = self
            .key_columns
            .iter()
            .chain(&self.value_columns)
            .enumerate()
            .filter(|(_, c)| !hidden.contains(&c.as_str()))
            .collect();
        let mut s = format!("# {title}\n\n{header}\n\n|");
        for (_, c) in &columns {
            let _ = write!(s, " {c} |");
        }
        s.push_str("\n|");
        for _ in &columns {
            s.push_str("---|");
        }
        s.push('\n');
        for row in &self.rows {
            let all: Vec<&String> = row.key.iter().chain(&row.values).collect();
            s.push('|');
            for (i, _) in &columns {
                let cell = all[*i].replace('|', "\\|");
                let _ = write!(s, " {} |", if cell.is_empty() { "–" } else { &cell });
            }
            s.push('\n');
        }
        s
    }
}

fn push_record<'a>(s: &mut String, fields: impl Iterator<Item = &'a String>) {
    let fields: Vec<String> = fields
        .map(|f| {
            if f.contains([',', '"', '\n', '\r']) {
                format!("\"{}\"", f.replace('"', "\"\""))
            } else {
                f.clone()
            }
        })
        .collect();
    s.push_str(&fields.join(","));
    s.push('\n');
}

/// Records of a CSV text (RFC 4180: quoted fields may hold commas, quotes and newlines).
fn parse_csv(text: &str) -> anyhow::Result<Vec<Vec<String>>> {
    let mut records = Vec::new();
    let mut record = Vec::new();
    let mut field = String::new();
    let mut chars = text.chars().peekable();
    let mut quoted = false;
    let mut line = 1;
    while let Some(c) = chars.next() {
        if quoted {
            match c {
                '"' if chars.peek() == Some(&'"') => {
                    chars.next();
                    field.push('"');
                }
                '"' => quoted = false,
                c => {
                    if c == '\n' {
                        line += 1;
                    }
                    field.push(c);
                }
            }
            continue;
        }
        match c {
            '"' if field.is_empty() => quoted = true,
            ',' => record.push(std::mem::take(&mut field)),
            '\r' => {}
            '\n' => {
                record.push(std::mem::take(&mut field));
                records.push(std::mem::take(&mut record));
                line += 1;
            }
            c => field.push(c),
        }
    }
    if quoted {
        bail!("line {line}: a quoted field is not closed");
    }
    if !field.is_empty() || !record.is_empty() {
        record.push(field);
        records.push(record);
    }
    Ok(records)
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::progress::NoProgress;

    fn strings(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn rows_survive_the_csv_round_trip_with_awkward_fields() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        let mut t = Table::open(&path, &["scene", "method"], &["error", "note"]).unwrap();
        assert!(t.rows().is_empty());
        let row = Row {
            key: strings(&["a,b", "say \"hi\""]),
            values: strings(&["1.5", "two\nlines"]),
        };
        t.insert(row.clone()).unwrap();
        t.insert(Row {
            key: strings(&["c", "d"]),
            values: strings(&["", "x"]),
        })
        .unwrap();
        t.write_csv().unwrap();
        let back = Table::open(&path, &["scene", "method"], &["error", "note"]).unwrap();
        assert_eq!(back.rows(), t.rows());
        assert_eq!(back.cell(&back.rows()[0], "note"), Some("two\nlines"));
        assert_eq!(back.cell(&back.rows()[0], "scene"), Some("a,b"));
        assert_eq!(back.cell(&back.rows()[0], "nope"), None);
        // Same key → replaced, not added.
        t.insert(Row {
            key: strings(&["c", "d"]),
            values: strings(&["2", "y"]),
        })
        .unwrap();
        assert_eq!(t.rows().len(), 2);
        assert_eq!(t.rows()[1].values, strings(&["2", "y"]));
        assert!(
            t.insert(Row {
                key: strings(&["c"]),
                values: strings(&["2", "y"]),
            })
            .is_err()
        );
    }

    #[test]
    fn fill_computes_only_the_missing_keys() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        let key = |n: &u32| vec![n.to_string()];
        let mut t = Table::open(&path, &["n"], &["square"]).unwrap();
        let mut calls = Vec::new();
        let s = t
            .fill(
                &[2, 3],
                key,
                |n| {
                    calls.push(*n);
                    Ok(vec![(n * n).to_string()])
                },
                &NoProgress,
            )
            .unwrap();
        assert_eq!((s.computed, s.reused), (2, 0));
        let mut t = Table::open(&path, &["n"], &["square"]).unwrap();
        let s = t
            .fill(
                &[3, 4, 2],
                key,
                |n| {
                    calls.push(*n);
                    Ok(vec![(n * n).to_string()])
                },
                &NoProgress,
            )
            .unwrap();
        assert_eq!((s.computed, s.reused), (1, 2));
        assert_eq!(calls, [2, 3, 4]);
        // Grid order, whatever order the rows were computed in.
        let csv = std::fs::read_to_string(&path).unwrap();
        assert_eq!(csv, "n,square\n3,9\n4,16\n2,4\n");
        let md = t.markdown("Squares", "integers", &[]);
        assert!(
            md.contains("| n | square |\n|---|---|\n| 3 | 9 |\n"),
            "{md}"
        );
        assert!(!t.markdown("S", "", &["square"]).contains("square"));
    }

    #[test]
    fn a_csv_of_other_columns_is_refused_with_the_fix() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        std::fs::write(&path, "a,b\n1,2\n").unwrap();
        let e = Table::open(&path, &["n"], &["square"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.csv") && e.contains("delete it"), "{e}");
        std::fs::write(&path, "n,square\n1\n").unwrap();
        let e = format!("{:#}", Table::open(&path, &["n"], &["square"]).unwrap_err());
        assert!(e.contains("row 2 has 1 fields"), "{e}");
        std::fs::write(&path, "n,square\n\"1,2\n").unwrap();
        let e = format!("{:#}", Table::open(&path, &["n"], &["square"]).unwrap_err());
        assert!(e.contains("not closed"), "{e}");
    }

    #[test]
    fn a_csv_from_before_new_value_columns_keeps_its_rows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        std::fs::write(&path, "n,square\n3,9\n").unwrap();
        let mut t = Table::open(&path, &["n"], &["square", "cube"]).unwrap();
        assert_eq!(t.rows()[0].values, strings(&["9", ""]));
        t.insert(Row {
            key: strings(&["2"]),
            values: strings(&["4", "8"]),
        })
        .unwrap();
        t.write_csv().unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "n,square,cube\n3,9,\n2,4,8\n"
        );
        // Only key columns, or columns of another order, are not an older table.
        std::fs::write(&path, "n\n3\n").unwrap();
        assert!(Table::open(&path, &["n"], &["square"]).is_err());
        std::fs::write(&path, "n,cube\n3,27\n").unwrap();
        assert!(Table::open(&path, &["n"], &["square", "cube"]).is_err());
    }
}

//! The evaluation protocol of SPEC §7 (paper §6): leave-one-out retrieval over a labelled
//! collection with the Princeton Shape Benchmark measures ([`metrics`], [`retrieval`]), the
//! salient points' robustness to resolution, noise and motion ([`robustness`]), and the
//! parameter study that chose the defaults ([`study`]), and the tuning of the hybrid's
//! weights ([`tune`]). [`report`] writes what they found as
//! JSON, Markdown and plots.

pub mod disguise;
pub mod duplicates;
pub mod metrics;
pub mod partial;
pub mod report;
pub mod retrieval;
pub mod robustness;
pub mod study;
pub mod tune;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use salient_core::collection::find_meshes;
use salient_core::{Error, Result};

/// The file that names each model's class, `path<TAB>class` per line (an optional
/// `path<TAB>class` header first), paths relative to the collection.
pub const LABELS_FILE: &str = "labels.tsv";

/// A model of a labelled collection.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Model {
    /// Path relative to the collection, with `/` separators: the model's name in reports.
    pub id: String,
    pub path: PathBuf,
    pub class: String,
}

/// A folder of meshes with a class for each (SPEC §7: `CLASS/MODEL.ext`), models sorted by id.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LabelledCollection {
    pub root: PathBuf,
    pub models: Vec<Model>,
}

impl LabelledCollection {
    /// The models listed in `dir/labels.tsv` when there is one, else every mesh below `dir`
    /// labelled by its first folder.
    pub fn open(dir: &Path) -> Result<Self> {
        let labels = dir.join(LABELS_FILE);
        let mut models = if labels.is_file() {
            Self::from_labels(dir, &labels)?
        } else {
            Self::from_folders(dir)?
        };
        if models.is_empty() {
            return Err(Error::Labels {
                path: dir.to_path_buf(),
                message: "no labelled meshes found".into(),
            });
        }
        models.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(Self {
            root: dir.to_path_buf(),
            models,
        })
    }

    fn from_labels(dir: &Path, labels: &Path) -> Result<Vec<Model>> {
        let text = std::fs::read_to_string(labels).map_err(|source| Error::Io {
            path: labels.to_path_buf(),
            source,
        })?;
        let bad = |line: usize, message: String| Error::Labels {
            path: labels.to_path_buf(),
            message: format!("line {line}: {message}"),
        };
        let mut models = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim_end_matches('\r');
            if line.trim().is_empty() || (i == 0 && line == "path\tclass") {
                continue;
            }
            let Some((id, class)) = line.split_once('\t') else {
                return Err(bad(i + 1, "expected `path<TAB>class`".into()));
            };
            let path = dir.join(id);
            if !path.is_file() {
                return Err(bad(i + 1, format!("{} does not exist", path.display())));
            }
            models.push(Model {
                id: id.to_string(),
                path,
                class: class.trim().to_string(),
            });
        }
        Ok(models)
    }

    fn from_folders(dir: &Path) -> Result<Vec<Model>> {
        find_meshes(dir)?
            .into_iter()
            .map(|path| {
                let relative = path.strip_prefix(dir).unwrap_or(&path);
                let parts: Vec<String> = relative
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy().into_owned())
                    .collect();
                match parts.as_slice() {
                    [class, _, ..] => Ok(Model {
                        id: parts.join("/"),
                        class: class.clone(),
                        path,
                    }),
                    _ => Err(Error::Labels {
                        path: path.clone(),
                        message: format!(
                            "a mesh outside a class folder and no {LABELS_FILE}: expected CLASS/MODEL.ext"
                        ),
                    }),
                }
            })
            .collect()
    }

    /// Each model's class.
    pub fn classes(&self) -> Vec<&str> {
        self.models.iter().map(|m| m.class.as_str()).collect()
    }

    /// How many models each class has.
    pub fn class_sizes(&self) -> BTreeMap<String, usize> {
        let mut sizes = BTreeMap::new();
        for m in &self.models {
            *sizes.entry(m.class.clone()).or_default() += 1;
        }
        sizes
    }
}

/// What long evaluation steps tell their caller, for a progress bar. Called from worker
/// threads, hence `Sync`.
pub trait Progress: Sync {
    /// A step of `total` items begins.
    fn start(&self, step: &str, total: usize);
    /// One item (named, where it has a name) is done.
    fn advance(&self, item: &str);
    /// The step is over.
    fn finish(&self);
}

/// Reports nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct Silent;

impl Progress for Silent {
    fn start(&self, _: &str, _: usize) {}
    fn advance(&self, _: &str) {}
    fn finish(&self) {}
}

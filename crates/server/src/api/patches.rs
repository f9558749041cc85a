//! Every model's stored patch descriptors ([`salient_core::descriptor::patch::Packed`]; `docs/results/partial/`),
//! which pick the models a partial search verifies, made in the background: off the upload's
//! path, once the extraction pool has no request to serve, and only on cores nothing else
//! needs ([`super::pool::Pool::run_idle`]), so an ingest runs at the rate it would without
//! them and they follow it. Made for each model stored since, and at
//! start for every model without them (stored by an earlier release, or with another
//! layout). Meanwhile a model without patches is left to the fit
//! ([`salient_core::rank::Query::Part`]).

use std::collections::{BTreeMap, HashSet};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use prometheus_client::metrics::gauge::Gauge;
use tokio::sync::{watch, Notify};

use super::error::AppError;
use super::App;
use crate::model::{now_unix, ModelId};
use crate::store::Derived;
use salient_core::descriptor::patch::PACKED_LAYOUT;
use salient_core::mesh::load_bytes;
use salient_core::params::Limits;
use salient_core::partial::stored_patches;

/// The name of the claim on counting the models that lack patches, on a shared store.
const CLAIM: &str = "patches";

/// The models whose patches are to be made.
pub struct Patcher {
    queue: Mutex<Queue>,
    wake: Notify,
    /// Models whose patches are to be made or being made; `None` until the start's count.
    pending: watch::Sender<Option<usize>>,
    /// The same, for `/metrics`.
    gauge: Gauge,
}

#[derive(Default)]
struct Queue {
    lacking: BTreeMap<ModelId, Why>,
    working: bool,
}

/// Why a model's patches are to be made, which says whether to look for them first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Why {
    /// This replica stored or re-described it: whatever patches it has are of its old upload.
    Stored,
    /// A count found none: another replica may have made them since.
    Counted,
}

impl Patcher {
    pub fn new(gauge: Gauge) -> Self {
        Self {
            queue: Mutex::default(),
            wake: Notify::new(),
            pending: watch::Sender::new(None),
            gauge,
        }
    }

    /// A model was stored or replaced: its patches are to be made.
    pub fn stored(&self, id: ModelId) {
        self.change(|queue| {
            queue.lacking.insert(id, Why::Stored);
        });
        self.wake.notify_one();
    }

    pub fn pending(&self) -> watch::Receiver<Option<usize>> {
        self.pending.subscribe()
    }

    fn change<T>(&self, f: impl FnOnce(&mut Queue) -> T) -> T {
        let mut queue = self.queue.lock().expect("never poisoned");
        let out = f(&mut queue);
        let pending = queue.lacking.len() + usize::from(queue.working);
        self.pending.send_if_modified(|p| {
            // Before the start's count, the models stored since are not all that is pending.
            let changed = p.is_some() && *p != Some(pending);
            if changed {
                *p = Some(pending);
                self.gauge.set(pending as i64);
            }
            changed
        });
        out
    }

    /// A count: every model it found without patches is pending (each count is announced,
    /// even one that changes nothing).
    fn counted(&self, lacking: impl IntoIterator<Item = ModelId>) {
        let mut queue = self.queue.lock().expect("never poisoned");
        for id in lacking {
            queue.lacking.entry(id).or_insert(Why::Counted);
        }
        let pending = queue.lacking.len() + usize::from(queue.working);
        self.pending.send_replace(Some(pending));
        self.gauge.set(pending as i64);
    }
}

/// Makes the patches of every model that lacks them, then of each one stored, for as long as
/// the service runs. Needs a Tokio runtime.
pub fn start(app: &Arc<App>) {
    tokio::spawn(run(app.clone()));
}

async fn run(app: Arc<App>) {
    let patcher = &app.patcher;
    // A store of its own is counted once, at start: every model stored since is queued
    // here. On a store shared by replicas, each makes those of its own writes, and one at a
    // time counts and makes the rest (stored by an earlier release, or by a replica stopped
    // before it made them), holding a claim until its queue is empty; every replica tries
    // for that claim again every `patch_recount_secs`.
    let shared = app.store.shared().is_some();
    let recount = Duration::from_secs(app.config.patch_recount_secs);
    let mut next_count = Some(Instant::now());
    let mut claim = None;
    loop {
        if next_count.is_some_and(|at| at <= Instant::now()) {
            next_count = shared.then(|| Instant::now() + recount);
            match count(&app, claim.is_some()).await {
                Ok(Counted::Lacking(held, lacking)) => {
                    claim = claim.or(held);
                    patcher.counted(lacking);
                }
                Ok(Counted::Elsewhere) => patcher.counted([]),
                Err(error) => {
                    tracing::warn!(%error, "cannot count the models without patches; partial search fits them by their features");
                    next_count = Some(Instant::now() + recount);
                }
            }
        }
        let next = patcher.change(|queue| {
            let next = queue.lacking.pop_first();
            queue.working = next.is_some();
            next
        });
        let Some((id, why)) = next else {
            // Made: another replica may count what this one left.
            drop(claim.take());
            match next_count {
                Some(at) => {
                    let _ = tokio::time::timeout_at(at.into(), patcher.wake.notified()).await;
                }
                None => patcher.wake.notified().await,
            }
            continue;
        };
        app.pool.idle().await;
        if !make(&app, &id, why).await {
            tracing::warn!(%id, "cannot make a model's patches; partial search fits it by its features");
        }
        patcher.change(|queue| queue.working = false);
    }
}

/// What a count found.
enum Counted {
    /// The models without patches (with the claim, on a shared store, unless already held).
    Lacking(Option<Box<dyn Send>>, Vec<ModelId>),
    /// Another replica holds the claim: it counts.
    Elsewhere,
}

/// The models of the catalogue whose stored patches are missing or of another layout. On a
/// shared store, under the claim (`holding` it already, or taken now), and leaving out those
/// stored in the last `patch_grace_secs`, which the replica that stored them is making.
async fn count(app: &Arc<App>, holding: bool) -> Result<Counted, AppError> {
    let held = if holding {
        None
    } else {
        match app
            .with_store(|store| store.shared().map(|s| s.try_lock(CLAIM)).transpose())
            .await?
        {
            Some(None) => return Ok(Counted::Elsewhere),
            held => held.flatten(),
        }
    };
    let made = app
        .with_store(|store| {
            store
                .derived_ids(Derived::Patches, &[PACKED_LAYOUT])
                .collect::<Result<HashSet<ModelId>, _>>()
        })
        .await?;
    let recent = match app.store.shared() {
        Some(_) => now_unix().saturating_sub(app.config.patch_grace_secs),
        None => u64::MAX,
    };
    let snapshot = app.catalog.snapshot();
    let lacking = snapshot
        .records
        .iter()
        .filter(|(id, record)| !made.contains(*id) && record.updated_unix < recent)
        .map(|(id, _)| id.clone())
        .collect();
    Ok(Counted::Lacking(held, lacking))
}

/// Makes and keeps the patches of model `id` from its stored upload; true when made, or when
/// the model was deleted or replaced meanwhile (a replaced one is queued again), or when a
/// count's model was made by another replica since.
async fn make(app: &Arc<App>, id: &ModelId, why: Why) -> bool {
    let Some(record) = app.catalog.snapshot().records.get(id).cloned() else {
        return true;
    };
    if why == Why::Counted {
        let key = id.clone();
        let made = app
            .with_store(move |store| store.derived(Derived::Patches, key.as_str()))
            .await;
        if let Ok(Some(entry)) = made {
            if entry.first() == Some(&PACKED_LAYOUT) {
                return true;
            }
        }
    }
    let key = id.clone();
    let Ok(Some(upload)) = app
        .with_store(move |store| store.upload(key.as_str()))
        .await
    else {
        return false;
    };
    if upload.content_hash() != record.content_hash {
        return true;
    }
    let mesh = app.config.params.mesh.clone();
    let made = app
        .pool
        .run_idle(move || {
            // Accepted under the limits of its upload: today's may be lower.
            let raw = load_bytes(
                &upload.mesh,
                upload.format,
                &upload.resources,
                &Limits::unlimited(),
            )?;
            // Neither the file nor the loaded mesh is kept longer than it is needed.
            drop(upload);
            stored_patches(raw, &mesh)
        })
        .await;
    let Ok(Ok(packed)) = made else {
        return false;
    };
    let (key, entry) = (id.clone(), packed.to_bytes());
    app.with_store(move |store| {
        store.put_derived(Derived::Patches, key.as_str(), &record.content_hash, &entry)
    })
    .await
    .is_ok()
}

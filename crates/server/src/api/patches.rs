//! Every model's stored patch descriptors ([`salient_core::descriptor::patch::Packed`]; `docs/results/partial/`),
//! which pick the models a partial search verifies, made in the background: off the upload's
//! path, once the extraction pool has no request to serve, and only on cores nothing else
//! needs ([`super::pool::Pool::run_idle`]), so an ingest runs at the rate it would without
//! them and they follow it. Made for each model stored since, and at
//! start for every model without them (stored by an earlier release, or with another
//! layout). Meanwhile a model without patches is left to the fit
//! ([`salient_core::rank::Query::Part`]).

use std::collections::{BTreeSet, HashSet};
use std::sync::{Arc, Mutex};

use prometheus_client::metrics::gauge::Gauge;
use tokio::sync::{watch, Notify};

use super::App;
use crate::model::ModelId;
use crate::store::Derived;
use salient_core::descriptor::patch::Packed;
use salient_core::mesh::load_bytes;
use salient_core::params::Limits;
use salient_core::partial::stored_patches;

/// The name of the claim on counting the models that lack patches, on a shared store.
const CLAIM: &str = "patches";
/// How often a replica without that claim tries for it again.
const TRY_CLAIM_EVERY: std::time::Duration = std::time::Duration::from_secs(30);

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
    lacking: BTreeSet<ModelId>,
    working: bool,
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
            queue.lacking.insert(id);
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

    /// The start's count: every model without patches is pending.
    fn counted(&self, lacking: impl IntoIterator<Item = ModelId>) {
        let mut queue = self.queue.lock().expect("never poisoned");
        queue.lacking.extend(lacking);
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
    // On a store shared by replicas, one counts and makes the models lacking patches (those
    // stored by an earlier release, or by a replica that stopped before making them),
    // holding a claim until its queue is empty; the others make those of their own writes
    // and try for the claim again now and then.
    let mut counted = false;
    let mut claim = None;
    loop {
        if !counted {
            match app
                .with_store(|store| store.shared().map(|s| s.try_lock(CLAIM)).transpose())
                .await
            {
                Ok(None) => counted = true,
                Ok(Some(Some(held))) => (claim, counted) = (Some(held), true),
                Ok(Some(None)) => patcher.counted([]),
                Err(error) => tracing::warn!(%error, "cannot claim the patches to make"),
            }
            if counted {
                match lacking(&app).await {
                    Ok(lacking) => patcher.counted(lacking),
                    Err(error) => {
                        tracing::error!(%error, "cannot read the stored patches; partial search keeps to the fit");
                        return;
                    }
                }
            }
        }
        let next = patcher.change(|queue| {
            let next = queue.lacking.pop_first();
            queue.working = next.is_some();
            next
        });
        let Some(id) = next else {
            // Made: another replica may count what it left.
            drop(claim.take());
            if counted {
                patcher.wake.notified().await;
            } else {
                let _ = tokio::time::timeout(TRY_CLAIM_EVERY, patcher.wake.notified()).await;
            }
            continue;
        };
        app.pool.idle().await;
        if !make(&app, &id).await {
            tracing::warn!(%id, "cannot make a model's patches; partial search fits it by its features");
        }
        patcher.change(|queue| queue.working = false);
    }
}

/// The models of the catalogue whose stored patches are missing or of another layout.
async fn lacking(app: &Arc<App>) -> Result<Vec<ModelId>, super::error::AppError> {
    let made = app
        .with_store(|store| {
            store
                .all_derived(Derived::Patches)
                .filter_map(|entry| match entry {
                    Ok((id, bytes)) => Packed::from_bytes(&bytes).map(|_| Ok(id)),
                    Err(e) => Some(Err(e)),
                })
                .collect::<Result<HashSet<ModelId>, _>>()
        })
        .await?;
    let snapshot = app.catalog.snapshot();
    Ok(snapshot
        .records
        .keys()
        .filter(|id| !made.contains(*id))
        .cloned()
        .collect())
}

/// Makes and keeps the patches of model `id` from its stored upload; true when made, or when
/// the model was deleted or replaced meanwhile (a replaced one is queued again).
async fn make(app: &Arc<App>, id: &ModelId) -> bool {
    let Some(record) = app.catalog.snapshot().records.get(id).cloned() else {
        return true;
    };
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

//! The ranking pools. Ranking runs on rayon pools of its own: on the global pool, which
//! extraction's parallel loops fill, a search waited for the extractions in progress (during
//! an ingest, the p99 latency of `similar` over 1 000 models went from 33 ms to 2.2 s). And
//! each ranking gets a pool to itself: rankings sharing one pool share its threads by work
//! stealing, where a thread waiting inside one ranking may take up another whole one, so a
//! ranking ends only after others it never waited for (at 100 000 models with four clients,
//! the exhaustive `d2` ranking, 14 ms of one thread, had a p99 of 161 ms; `benches/load.rs`).
//! So `rankings` pools share the cores out, and rankings take turns for them in arrival order
//! (tokio's semaphore is fair), counted while they wait.

use std::sync::{Arc, Mutex};

use prometheus_client::metrics::gauge::Gauge;
use rayon::{ThreadPool, ThreadPoolBuildError, ThreadPoolBuilder};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

pub struct Rankers {
    free: Mutex<Vec<ThreadPool>>,
    turns: Arc<Semaphore>,
    waiting: Gauge,
}

impl Rankers {
    /// `rankings` pools, the cores shared out between them; `waiting` counts the rankings
    /// waiting for their turn.
    pub fn new(rankings: usize, waiting: Gauge) -> Result<Self, ThreadPoolBuildError> {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let free = (0..rankings)
            .map(|r| {
                ThreadPoolBuilder::new()
                    .num_threads((cores / rankings).max(1))
                    .thread_name(move |i| format!("salient-rank-{r}-{i}"))
                    .build()
            })
            .collect::<Result<_, _>>()?;
        Ok(Self {
            free: Mutex::new(free),
            turns: Arc::new(Semaphore::new(rankings)),
            waiting,
        })
    }

    /// Waits for a free pool, behind the rankings that asked before.
    pub async fn turn(self: &Arc<Self>) -> Turn {
        self.waiting.inc();
        // Counted down also when the caller gives up waiting (the client went away).
        let _waiting = scopeguard::guard((), |()| {
            self.waiting.dec();
        });
        let permit = self.turns.clone().acquire_owned().await;
        Turn {
            rankers: self.clone(),
            _permit: permit.expect("the semaphore is never closed"),
        }
    }
}

/// A ranking's right to a pool, held until the ranking ends, even if its caller has gone.
pub struct Turn {
    rankers: Arc<Rankers>,
    _permit: OwnedSemaphorePermit,
}

impl Turn {
    /// Runs `f` on a pool of its own, given back before the turn ends (also on a panic).
    pub fn install<T: Send>(self, f: impl FnOnce() -> T + Send) -> T {
        let free = &self.rankers.free;
        let pool = free.lock().expect("never poisoned").pop();
        let pool = scopeguard::guard(pool.expect("a pool for every turn"), |pool| {
            free.lock().expect("never poisoned").push(pool);
        });
        pool.install(f)
    }
}

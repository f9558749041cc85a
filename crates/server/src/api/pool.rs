//! The bounded extraction pool: CPU-heavy extraction runs on tokio's blocking threads, at
//! most `workers` at once, with at most `queue_depth` more waiting. A request that finds the
//! queue full is answered 503 at once instead of piling up; one that waits past the time
//! limit is answered 503 too, while its job (which cannot be interrupted) keeps its permit
//! until it ends, so the pool never runs more than `workers` jobs. A job whose caller gave up
//! before a worker was free (the client went away, or the time limit passed) never runs.
//! Background work runs at a lower priority than requests: on a worker, waited for without
//! taking a queue slot ([`Pool::run_background`]), or on a thread of its own that runs only
//! on idle cores ([`Pool::run_idle`]).
//! Jobs run in the tracing span of their caller.

use std::sync::Arc;
use std::time::Duration;

use rayon::{ThreadPool, ThreadPoolBuildError, ThreadPoolBuilder};
use tokio::sync::{Notify, Semaphore};

use super::error::AppError;

#[derive(Debug)]
pub struct Pool {
    admitted: Arc<Semaphore>,
    running: Arc<Semaphore>,
    capacity: usize,
    timeout: Duration,
    /// Told when the last admitted job ends ([`Pool::idle`]).
    drained: Arc<Notify>,
    /// The thread of [`Pool::run_idle`].
    idle_thread: Arc<ThreadPool>,
}

impl Pool {
    pub fn new(
        workers: usize,
        queue_depth: usize,
        timeout: Duration,
    ) -> Result<Self, ThreadPoolBuildError> {
        let idle_thread = ThreadPoolBuilder::new()
            .num_threads(1)
            .thread_name(|_| "salient-idle".into())
            .build()?;
        Ok(Self {
            admitted: Arc::new(Semaphore::new(workers + queue_depth)),
            running: Arc::new(Semaphore::new(workers)),
            capacity: workers + queue_depth,
            timeout,
            drained: Arc::new(Notify::new()),
            idle_thread: Arc::new(idle_thread),
        })
    }

    /// Returns once no admitted job is running or waiting: background work that should not
    /// delay requests waits for this before it asks for a worker.
    pub async fn idle(&self) {
        loop {
            let drained = self.drained.notified();
            tokio::pin!(drained);
            // Registered before the check, so an end between the check and the wait counts.
            drained.as_mut().enable();
            if self.in_flight() == 0 {
                return;
            }
            drained.await;
        }
    }

    /// Jobs admitted (running or waiting).
    pub fn in_flight(&self) -> usize {
        self.capacity - self.admitted.available_permits()
    }

    /// Runs `job` on a blocking thread once a worker is free.
    pub async fn run<T: Send + 'static>(
        &self,
        job: impl FnOnce() -> T + Send + 'static,
    ) -> Result<T, AppError> {
        let admitted = Admitted {
            permit: Some(self.admitted.clone().try_acquire_owned().map_err(|_| {
                AppError::Overloaded {
                    retry_after_secs: 1,
                }
            })?),
            pool: (self.admitted.clone(), self.capacity, self.drained.clone()),
        };
        match tokio::time::timeout(self.timeout, self.run_with(admitted, job)).await {
            Ok(result) => result,
            Err(_) => Err(AppError::Timeout(self.timeout.as_secs())),
        }
    }

    /// Runs `job` once a worker is free, however long that takes: for background work,
    /// which must neither fill the queue that uploads are refused by nor time out.
    ///
    /// The job runs on a thread of rayon's pool, which has the extraction niceness
    /// ([`lower_extraction_priority`]), so that searches get the cores first. On a tokio
    /// blocking thread, whose niceness is the process's, the patches a start makes for every
    /// stored model (~90 ms of one thread each, serial) took a third of the cores from the
    /// rankings: in the load bench at 100 000 models, hybrid `similar` p50 54 ms.
    pub async fn run_background<T: Send + 'static>(
        &self,
        job: impl FnOnce() -> T + Send + 'static,
    ) -> Result<T, AppError> {
        // Called from outside the pool, `scope` runs its body on one of the pool's threads
        // while this blocking thread waits.
        self.run_with((), move || rayon::scope(|_| job())).await
    }

    /// Runs `job` on a thread of its own which, once [`Pool::lower_idle_priority`] has run,
    /// the scheduler runs only on a core with nothing else to run (`SCHED_IDLE`): for work
    /// that may wait for as long as the service is busy, the stored patches. At niceness 10 a
    /// thread still takes ~10 % of a busy core (the scheduler's weights 110 against 1 024),
    /// and the patches a start makes for 100 000 stored models (~2.5 CPU-hours) took that
    /// from the rankings all through the load bench. It takes no worker: held by a job the
    /// scheduler keeps waiting, a worker would be kept from the uploads.
    pub async fn run_idle<T: Send + 'static>(
        &self,
        job: impl FnOnce() -> T + Send + 'static,
    ) -> Result<T, AppError> {
        let idle_thread = self.idle_thread.clone();
        blocking(move || idle_thread.install(job)).await
    }

    /// Puts [`Pool::run_idle`]'s thread in `SCHED_IDLE`: for the serving process, once (an
    /// unprivileged thread cannot leave it). Linux only.
    pub fn lower_idle_priority(&self) {
        #[cfg(target_os = "linux")]
        self.idle_thread.broadcast(|_| {
            let param = libc::sched_param { sched_priority: 0 };
            // SAFETY: `param` outlives the call, which only reads it; pid 0 is this thread.
            let done = unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) };
            if done != 0 {
                tracing::warn!("cannot give the background thread the idle priority");
            }
        });
    }

    /// Waits for a worker, then runs `job` on a blocking thread holding it and `permit`.
    async fn run_with<T: Send + 'static, P: Send + 'static>(
        &self,
        permit: P,
        job: impl FnOnce() -> T + Send + 'static,
    ) -> Result<T, AppError> {
        let worker = self
            .running
            .clone()
            .acquire_owned()
            .await
            .expect("the pool's semaphore is never closed");
        blocking(move || {
            let result = job();
            // The queue slot goes before the worker: whoever gets the worker next finds
            // the slot free already.
            drop((permit, worker));
            result
        })
        .await
    }
}

/// Runs `job` on a blocking thread, in the caller's tracing span.
async fn blocking<T: Send + 'static>(
    job: impl FnOnce() -> T + Send + 'static,
) -> Result<T, AppError> {
    let span = tracing::Span::current();
    tokio::task::spawn_blocking(move || {
        let _span = span.enter();
        let result = job();
        release_free_memory();
        result
    })
    .await
    .map_err(|join| AppError::Internal(format!("extraction failed: {join}")))
}

/// A request's place in the pool (running or waiting); when the last one goes, whether its
/// job ended or never ran (its caller gave up), [`Pool::idle`] is told.
struct Admitted {
    permit: Option<tokio::sync::OwnedSemaphorePermit>,
    pool: (Arc<Semaphore>, usize, Arc<Notify>),
}

impl Drop for Admitted {
    fn drop(&mut self) {
        drop(self.permit.take());
        let (admitted, capacity, drained) = &self.pool;
        if admitted.available_permits() == *capacity {
            drained.notify_waiters();
        }
    }
}

/// Hands the allocator's free memory back to the system after an extraction, or after the
/// start's parallel decoding. An extraction allocates tens of megabytes across rayon's
/// threads, and glibc kept what they freed in its per-thread arenas: in the load bench at
/// 100 000 models the server grew from 630 MiB resident after start-up to 973 MiB after its
/// uploads. (glibc only; other allocators return memory themselves.)
pub(crate) fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `malloc_trim` takes no pointers; it only walks the allocator's own free lists,
    // under the allocator's locks, and may be called from any thread at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Caps glibc's malloc arenas at two per core, for the serving process before it loads the
/// store. Each thread that allocates for the first time — each of tokio's blocking threads an
/// upload or a search runs on — would otherwise get an arena of its own (up to 8 per core),
/// which keeps what its threads freed. Load bench at 100 000 models, all five methods' runs,
/// 2 cores: resident after them 828 MiB with glibc's default, 789 MiB with 4 arenas and 755
/// with 2; but with 2, rankings during uploads contend for them (held-out ranking p50 58 ms
/// against 45 with 4 or the default). Set only after the start's load, the cap left 820 MiB.
/// An operator's `MALLOC_ARENA_MAX` is left to rule. (glibc only; other allocators manage
/// their own.)
pub fn limit_malloc_arenas() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    if std::env::var_os("MALLOC_ARENA_MAX").is_none() {
        let arenas = 2 * std::thread::available_parallelism().map_or(1, |n| n.get());
        // SAFETY: `mallopt` takes no pointers; it sets a limit glibc reads when a thread next
        // needs an arena.
        unsafe {
            libc::mallopt(libc::M_ARENA_MAX, arenas.try_into().unwrap_or(i32::MAX));
        }
    }
}

/// Gives every thread of rayon's global pool — where extraction's parallel loops run;
/// ranking has pools of its own (`rankers`) — the niceness `nice`, so that the scheduler runs
/// a search before the extractions of an ingest: at 100 000 models, hybrid `similar`'s p99
/// during an ingest was 2.2× its p99 without one (1 245 against 558 ms); with this and the
/// ranking pools, 128 against 115 ms (`benches/load.rs`). Linux only (a thread's own niceness); the serial parts of an
/// extraction run on tokio's blocking threads, which keep theirs. An unprivileged process may
/// raise its niceness but not lower it again, so this is for the serving process.
pub fn lower_extraction_priority(nice: i32) {
    #[cfg(target_os = "linux")]
    rayon::broadcast(|_| {
        // SAFETY: `gettid` and `setpriority` take plain integers and touch no memory of ours;
        // `PRIO_PROCESS` with a thread id changes that thread alone.
        let done = unsafe {
            let thread = libc::gettid() as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, thread, nice)
        };
        if done != 0 {
            tracing::warn!("cannot lower the priority of an extraction thread");
        }
    });
    #[cfg(not(target_os = "linux"))]
    let _ = nice;
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::mpsc;

    use super::*;

    /// A job that says when it runs, then waits to be released.
    fn held(
        pool: &Arc<Pool>,
    ) -> (
        tokio::task::JoinHandle<Result<(), AppError>>,
        mpsc::Sender<()>,
    ) {
        let (started, wait_started) = mpsc::channel();
        let (release, wait_release) = mpsc::channel::<()>();
        let pool = pool.clone();
        let job = tokio::spawn(async move {
            pool.run(move || {
                started.send(()).unwrap();
                let _ = wait_release.recv();
            })
            .await
        });
        wait_started.recv().unwrap();
        (job, release)
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_full_queue_is_refused_at_once() {
        let pool = Arc::new(Pool::new(1, 0, Duration::from_secs(600)).unwrap());
        let (job, release) = held(&pool);
        // The worker is busy and there is no queue: refused without waiting for it.
        assert!(matches!(
            pool.run(|| ()).await,
            Err(AppError::Overloaded {
                retry_after_secs: 1
            })
        ));
        release.send(()).unwrap();
        job.await.unwrap().unwrap();
        assert_eq!(pool.run(|| 7).await.unwrap(), 7);
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_timed_out_job_keeps_its_permit_until_it_ends() {
        let pool = Arc::new(Pool::new(1, 0, Duration::from_millis(20)).unwrap());
        let (job, release) = held(&pool);
        // The job waits for the test, so the time limit passes first: the caller gets its
        // answer ...
        assert!(matches!(job.await.unwrap(), Err(AppError::Timeout(_))));
        // ... while the job still runs and holds the only worker.
        assert_eq!(pool.in_flight(), 1);
        assert!(matches!(
            pool.run(|| ()).await,
            Err(AppError::Overloaded { .. })
        ));
        release.send(()).unwrap();
        // Waits for the worker (so for the job's end), then a new job is admitted.
        pool.run_background(|| ()).await.unwrap();
        assert_eq!(pool.in_flight(), 0);
        assert_eq!(pool.run(|| 7).await.unwrap(), 7);
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_job_whose_caller_has_gone_never_runs() {
        let pool = Arc::new(Pool::new(1, 1, Duration::from_secs(600)).unwrap());
        let (first, release) = held(&pool);
        let ran = Arc::new(AtomicBool::new(false));
        let (flag, waiting) = (ran.clone(), pool.clone());
        let gone = tokio::spawn(async move {
            waiting
                .run(move || flag.store(true, Ordering::SeqCst))
                .await
        });
        // Admitted (it holds the queue slot) and waiting for the worker.
        while pool.in_flight() < 2 {
            tokio::task::yield_now().await;
        }
        gone.abort();
        assert!(gone.await.unwrap_err().is_cancelled());
        assert_eq!(pool.in_flight(), 1);
        release.send(()).unwrap();
        first.await.unwrap().unwrap();
        pool.run_background(|| ()).await.unwrap();
        assert!(!ran.load(Ordering::SeqCst));
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn idle_waits_for_every_admitted_job_to_end() {
        let pool = Arc::new(Pool::new(1, 1, Duration::from_secs(600)).unwrap());
        pool.idle().await;
        let (job, release) = held(&pool);
        let (waiting, pending) = (pool.clone(), pool.clone());
        let idle = tokio::spawn(async move { waiting.idle().await });
        // A second job, admitted and waiting for the worker, whose caller goes away.
        let gone = tokio::spawn(async move { pending.run(|| ()).await });
        while pool.in_flight() < 2 {
            tokio::task::yield_now().await;
        }
        gone.abort();
        assert!(gone.await.unwrap_err().is_cancelled());
        assert!(!idle.is_finished(), "the first job still runs");
        release.send(()).unwrap();
        job.await.unwrap().unwrap();
        idle.await.unwrap();
        assert_eq!(pool.in_flight(), 0);
    }

    #[tokio::test]
    async fn background_jobs_run_on_the_extraction_threads() {
        let pool = Pool::new(1, 0, Duration::from_secs(600)).unwrap();
        let on_rayon = pool
            .run_background(|| rayon::current_thread_index().is_some())
            .await
            .unwrap();
        assert!(
            on_rayon,
            "a background job runs on rayon's (lowered) threads"
        );
        let on_rayon = pool.run(|| rayon::current_thread_index().is_some()).await;
        assert!(
            !on_rayon.unwrap(),
            "a request's job runs on a blocking thread"
        );
    }

    #[tokio::test]
    async fn idle_jobs_run_on_a_thread_of_their_own_at_the_idle_priority() {
        let pool = Pool::new(1, 0, Duration::from_secs(600)).unwrap();
        let name = || std::thread::current().name().map(str::to_owned);
        let name = pool.run_idle(name).await.unwrap();
        assert_eq!(name.as_deref(), Some("salient-idle"));
        #[cfg(target_os = "linux")]
        {
            // SAFETY: takes a plain integer (0, this thread) and touches no memory of ours.
            let policy = || unsafe { libc::sched_getscheduler(0) };
            assert_ne!(pool.run_idle(policy).await.unwrap(), libc::SCHED_IDLE);
            pool.lower_idle_priority();
            assert_eq!(pool.run_idle(policy).await.unwrap(), libc::SCHED_IDLE);
        }
    }

    #[tokio::test]
    async fn a_panicking_job_is_an_internal_error() {
        let pool = Pool::new(1, 0, Duration::from_secs(600)).unwrap();
        let result = pool.run(|| -> () { panic!("a bug") }).await;
        assert!(matches!(result, Err(AppError::Internal(_))), "{result:?}");
        // The worker is free again.
        assert_eq!(pool.run(|| 7).await.unwrap(), 7);
    }
}

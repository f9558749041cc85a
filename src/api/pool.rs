//! The bounded extraction pool: CPU-heavy extraction runs on tokio's blocking threads, at
//! most `workers` at once, with at most `queue_depth` more waiting. A request that finds the
//! queue full is answered 503 at once instead of piling up; one that waits past the time
//! limit is answered 503 too, while its job (which cannot be interrupted) keeps its permit
//! until it ends, so the pool never runs more than `workers` jobs.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::Semaphore;

use super::error::AppError;

#[derive(Debug)]
pub struct Pool {
    admitted: Arc<Semaphore>,
    running: Arc<Semaphore>,
    capacity: usize,
    timeout: Duration,
}

impl Pool {
    pub fn new(workers: usize, queue_depth: usize, timeout: Duration) -> Self {
        Self {
            admitted: Arc::new(Semaphore::new(workers + queue_depth)),
            running: Arc::new(Semaphore::new(workers)),
            capacity: workers + queue_depth,
            timeout,
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
        let admitted =
            self.admitted
                .clone()
                .try_acquire_owned()
                .map_err(|_| AppError::Overloaded {
                    retry_after_secs: 1,
                })?;
        let running = self.running.clone();
        let work = async move {
            let worker = running
                .acquire_owned()
                .await
                .expect("the pool's semaphore is never closed");
            tokio::task::spawn_blocking(move || {
                let result = job();
                drop((worker, admitted));
                result
            })
            .await
        };
        match tokio::time::timeout(self.timeout, work).await {
            Ok(Ok(value)) => Ok(value),
            Ok(Err(join)) => Err(AppError::Internal(format!("extraction failed: {join}"))),
            Err(_) => Err(AppError::Timeout(self.timeout.as_secs())),
        }
    }
}

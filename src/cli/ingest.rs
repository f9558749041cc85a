//! `salient ingest DIR --server URL`: the bulk client of the service. Uploads every mesh of a
//! folder with bounded concurrency, skips content the server already holds, retries what the
//! server could not take, and ends with a summary.
//!
//! Retrying an upload is safe because every upload names its model id: sending it twice
//! replaces the model with the same content.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};
use reqwest::header::{CONTENT_TYPE, RETRY_AFTER};
use reqwest::multipart::{Form, Part};
use reqwest::{RequestBuilder, Response, StatusCode};
use serde::Serialize;
use serde_json::Value;
use tokio::sync::Semaphore;
use tokio::task::JoinSet;

use crate::ingest::{self, parse_retry_after, Backoff, Item};
use salient_server::model::Upload;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder of meshes, searched recursively (hidden files and folders skipped).
    #[arg(required_unless_present = "manifest", conflicts_with = "manifest")]
    dir: Option<PathBuf>,
    /// A JSON Lines file, one `{"path", "id", "name", "tags", "class"}` per line (paths
    /// relative to it): the library's own ids and fields. A file already stored under its id
    /// is skipped, or only its fields are updated when they changed (no re-extraction).
    #[arg(long)]
    manifest: Option<PathBuf>,
    /// Base URL of the service, e.g. http://127.0.0.1:8080.
    #[arg(long, env = "SALIENT_SERVER")]
    server: String,
    /// Uploads in flight at once.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=256))]
    concurrency: u32,
    /// Use each file's first folder below DIR as its class.
    #[arg(long)]
    class_from_folder: bool,
    /// Tags of every model, comma-separated.
    #[arg(long)]
    tags: Option<String>,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
    /// Tries per request when the server is overloaded or unreachable.
    #[arg(long, default_value_t = Backoff::default().attempts, value_parser = clap::value_parser!(u32).range(1..=30))]
    attempts: u32,
    /// Time limit of one request, seconds (an upload includes the server's extraction).
    #[arg(long, default_value_t = 300)]
    timeout: u64,
    /// API key with the write scope (sent as `Authorization: Bearer KEY`).
    #[arg(long, env = "SALIENT_API_KEY", hide_env_values = true)]
    api_key: Option<String>,
}

/// What happened to one file.
enum Outcome {
    Added,
    /// Stored already; its fields were changed.
    Updated,
    Skipped,
    Failed(String),
}

#[derive(Serialize)]
struct Failure {
    path: String,
    id: String,
    reason: String,
}

#[derive(Serialize)]
struct Summary {
    files: usize,
    added: usize,
    updated: usize,
    skipped: usize,
    failed: usize,
    /// Requests sent again after a 429/502/503/504, a connection error or a timeout.
    retries: u64,
    seconds: f64,
    failures: Vec<Failure>,
}

/// The service's API as this client uses it.
struct Client {
    http: reqwest::Client,
    base: String,
    backoff: Backoff,
    retries: AtomicU64,
}

fn chain(error: reqwest::Error) -> String {
    format!("{:#}", anyhow::Error::from(error))
}

/// `HTTP 400 bad_mesh: …` from an error response and its JSON body, if it has one.
async fn describe(response: Response) -> String {
    let status = response.status();
    let body: Option<Value> = response.json().await.ok();
    match body
        .as_ref()
        .map(|b| (&b["error"]["code"], &b["error"]["message"]))
    {
        Some((Value::String(code), Value::String(message))) => {
            format!("HTTP {} {code}: {message}", status.as_u16())
        }
        _ => format!("HTTP {status}"),
    }
}

impl Client {
    /// Sends the request `make` builds, again after a pause while the server answers 429,
    /// 502, 503 or 504 or cannot be reached in time. Other answers are returned as they are.
    async fn send(&self, make: impl Fn() -> RequestBuilder) -> Result<Response, String> {
        let mut attempt = 1;
        loop {
            let (retry_after, failure) = match make().send().await {
                Ok(response)
                    if matches!(
                        response.status(),
                        StatusCode::TOO_MANY_REQUESTS
                            | StatusCode::BAD_GATEWAY
                            | StatusCode::SERVICE_UNAVAILABLE
                            | StatusCode::GATEWAY_TIMEOUT
                    ) =>
                {
                    let retry_after = response
                        .headers()
                        .get(RETRY_AFTER)
                        .and_then(|v| v.to_str().ok())
                        .and_then(parse_retry_after);
                    (retry_after, describe(response).await)
                }
                Ok(response) => return Ok(response),
                Err(e) if e.is_connect() || e.is_timeout() || e.is_request() => (None, chain(e)),
                Err(e) => return Err(chain(e)),
            };
            if !self.backoff.may_retry(attempt) {
                return Err(format!("{failure} (gave up after {attempt} attempts)"));
            }
            let jitter = rand::random::<f64>() * 0.25;
            tokio::time::sleep(self.backoff.delay(attempt - 1, retry_after, jitter)).await;
            self.retries.fetch_add(1, Ordering::Relaxed);
            attempt += 1;
        }
    }

    /// Fails unless `/healthz` answers, so that a wrong URL ends the run at once.
    async fn check(&self) -> anyhow::Result<()> {
        let url = format!("{}/healthz", self.base);
        let response = self
            .send(|| self.http.get(&url))
            .await
            .map_err(anyhow::Error::msg)?;
        if !response.status().is_success() {
            bail!("{}", describe(response).await);
        }
        Ok(())
    }

    /// The id of a stored model with this content hash.
    async fn find(&self, content_hash: &str) -> Result<Option<String>, String> {
        let url = format!("{}/v1/models", self.base);
        let query = [("content_hash", content_hash), ("limit", "1")];
        let response = self.send(|| self.http.get(&url).query(&query)).await?;
        if !response.status().is_success() {
            return Err(describe(response).await);
        }
        let page: Value = response.json().await.map_err(chain)?;
        Ok(page["models"][0]["id"].as_str().map(String::from))
    }

    /// The stored record of `id`, if there is one.
    async fn record(&self, id: &str) -> Result<Option<Value>, String> {
        let url = format!("{}/v1/models/{id}", self.base);
        let response = self.send(|| self.http.get(&url)).await?;
        match response.status() {
            StatusCode::NOT_FOUND => Ok(None),
            s if s.is_success() => response.json().await.map(Some).map_err(chain),
            _ => Err(describe(response).await),
        }
    }

    /// Sets a stored model's fields to `fields` (JSON `name`, `tags`, `class`).
    async fn patch(&self, id: &str, fields: &Value) -> Result<(), String> {
        let url = format!("{}/v1/models/{id}", self.base);
        let response = self.send(|| self.http.patch(&url).json(fields)).await?;
        if response.status().is_success() {
            Ok(())
        } else {
            Err(describe(response).await)
        }
    }

    /// For a manifest's item: skipped when its id holds this upload with these fields,
    /// updated when only the fields differ; `None` when it must be uploaded.
    async fn compare_stored(
        &self,
        item: &Item,
        upload: &Upload,
        tags: &[String],
    ) -> Option<Outcome> {
        let fields = serde_json::json!({
            "name": item.name, "tags": tags, "class": item.class, "up": item.up
        });
        let stored = match self.record(&item.id).await {
            Ok(Some(stored)) if stored["content_hash"] == upload.content_hash() => stored,
            Ok(_) => return None,
            Err(reason) => return Some(Outcome::Failed(reason)),
        };
        if ["name", "tags", "class", "up"]
            .iter()
            .all(|k| stored[k] == fields[k])
        {
            return Some(Outcome::Skipped);
        }
        Some(match self.patch(&item.id, &fields).await {
            Ok(()) => Outcome::Updated,
            Err(reason) => Outcome::Failed(reason),
        })
    }

    async fn ingest(&self, item: Item, tags: Option<&str>) -> Outcome {
        let read = {
            let item = item.clone();
            tokio::task::spawn_blocking(move || ingest::read_upload(&item)).await
        };
        let upload = match read {
            Ok(Ok(upload)) => Arc::new(upload),
            Ok(Err(e)) => return Outcome::Failed(e.to_string()),
            Err(e) => return Outcome::Failed(e.to_string()),
        };
        let tags: Vec<String> = match &item.tags {
            Some(own) => own.clone(),
            None => tags
                .into_iter()
                .flat_map(|t| t.split(','))
                .map(|t| t.trim().to_string())
                .filter(|t| !t.is_empty())
                .collect(),
        };
        if item.from_manifest {
            if let Some(outcome) = self.compare_stored(&item, &upload, &tags).await {
                return outcome;
            }
        } else {
            match self.find(upload.content_hash()).await {
                Ok(Some(_)) => return Outcome::Skipped,
                Ok(None) => {}
                Err(reason) => return Outcome::Failed(reason),
            }
        }
        let mut query = vec![("id", item.id.clone()), ("name", item.name.clone())];
        query.extend(item.class.clone().map(|c| ("class", c)));
        query.extend(item.up.map(|up| ("up", up.as_str().to_string())));
        if !tags.is_empty() {
            query.push(("tags", tags.join(",")));
        }
        let url = format!("{}/v1/models", self.base);
        // The mesh's own name: a zip's is its unpacked mesh's format.
        let file_name = item
            .relative
            .with_extension(upload.format.extension())
            .file_name()
            .map(|n| n.to_string_lossy().into_owned());
        let response = self
            .send(|| {
                let request = self.http.post(&url).query(&query);
                if upload.resources.is_empty() {
                    request
                        .header(CONTENT_TYPE, upload.format.media_type())
                        .body(upload.mesh.clone())
                } else {
                    request.multipart(form(&upload, file_name.clone().unwrap_or_default()))
                }
            })
            .await;
        match response {
            Ok(r) if r.status().is_success() => Outcome::Added,
            Ok(r) => Outcome::Failed(describe(r).await),
            Err(reason) => Outcome::Failed(reason),
        }
    }
}

/// A multi-file glTF as a form: the document first (the server takes the first file with a
/// mesh extension as the mesh), then each resource under the URI the document uses.
fn form(upload: &Upload, file_name: String) -> Form {
    let mesh = Part::bytes(upload.mesh.to_vec())
        .file_name(file_name)
        .mime_str(upload.format.media_type())
        .expect("a valid media type");
    upload
        .resources
        .iter()
        .fold(Form::new().part("file", mesh), |form, (uri, bytes)| {
            form.part(
                "resource",
                Part::bytes(bytes.to_vec()).file_name(uri.clone()),
            )
        })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let clock = Instant::now();
    let items = match (&args.manifest, &args.dir) {
        (Some(manifest), _) => ingest::plan_manifest(manifest)?,
        (None, Some(dir)) => ingest::plan(dir, args.class_from_folder)
            .with_context(|| format!("cannot list the meshes in {}", dir.display()))?,
        (None, None) => bail!("give a folder or --manifest FILE"),
    };
    let base = args.server.trim_end_matches('/').to_string();
    reqwest::Url::parse(&base).with_context(|| format!("invalid server URL {base:?}"))?;
    let mut headers = reqwest::header::HeaderMap::new();
    if let Some(key) = &args.api_key {
        let mut value = reqwest::header::HeaderValue::from_str(&format!("Bearer {key}"))
            .context("the API key is not a valid header value")?;
        value.set_sensitive(true);
        headers.insert(reqwest::header::AUTHORIZATION, value);
    }
    let client = Arc::new(Client {
        http: reqwest::Client::builder()
            .timeout(Duration::from_secs(args.timeout))
            .default_headers(headers)
            .build()
            .context("cannot start the HTTP client")?,
        base,
        backoff: Backoff {
            attempts: args.attempts,
            ..Backoff::default()
        },
        retries: AtomicU64::new(0),
    });
    let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    let outcomes = runtime.block_on(async {
        client
            .check()
            .await
            .with_context(|| format!("cannot reach the server at {}", client.base))?;
        let progress = ProgressBar::new(items.len() as u64).with_style(
            ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed} < {eta}]")
                .expect("a valid template"),
        );
        let slots = Arc::new(Semaphore::new(args.concurrency as usize));
        let tags: Option<Arc<str>> = args.tags.as_deref().map(Arc::from);
        let mut tasks = JoinSet::new();
        for (index, item) in items.iter().cloned().enumerate() {
            let (client, slots, tags, progress) = (
                client.clone(),
                slots.clone(),
                tags.clone(),
                progress.clone(),
            );
            tasks.spawn(async move {
                let _slot = slots.acquire_owned().await.expect("never closed");
                let outcome = client.ingest(item, tags.as_deref()).await;
                progress.inc(1);
                (index, outcome)
            });
        }
        let mut outcomes = Vec::with_capacity(items.len());
        while let Some(done) = tasks.join_next().await {
            outcomes.push(done.context("an upload task panicked")?);
        }
        progress.finish_and_clear();
        outcomes.sort_by_key(|(index, _)| *index);
        anyhow::Ok(outcomes)
    })?;

    let mut summary = Summary {
        files: items.len(),
        added: 0,
        updated: 0,
        skipped: 0,
        failed: 0,
        retries: client.retries.load(Ordering::Relaxed),
        seconds: clock.elapsed().as_secs_f64(),
        failures: Vec::new(),
    };
    for (index, outcome) in outcomes {
        match outcome {
            Outcome::Added => summary.added += 1,
            Outcome::Updated => summary.updated += 1,
            Outcome::Skipped => summary.skipped += 1,
            Outcome::Failed(reason) => {
                summary.failed += 1;
                summary.failures.push(Failure {
                    path: items[index].relative.display().to_string(),
                    id: items[index].id.clone(),
                    reason,
                });
            }
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "added {}, updated {}, skipped {}, failed {} of {} files in {:.1} s ({} retries)",
            summary.added,
            summary.updated,
            summary.skipped,
            summary.failed,
            summary.files,
            summary.seconds,
            summary.retries
        );
        for f in &summary.failures {
            println!("failed {} ({}): {}", f.path, f.id, f.reason);
        }
    }
    if summary.failed > 0 {
        bail!("{} of {} files failed", summary.failed, summary.files);
    }
    Ok(())
}

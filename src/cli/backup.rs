//! `salient backup --server URL`: asks a running service for a consistent snapshot of its
//! sled store (`POST /v1/admin/backup`), written to its backup folder while it serves.

use std::time::Duration;

use anyhow::{bail, Context};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Base URL of the service, e.g. http://127.0.0.1:8080.
    #[arg(long, env = "SALIENT_SERVER")]
    server: String,
    /// API key with the admin scope.
    #[arg(long, env = "SALIENT_API_KEY", hide_env_values = true)]
    api_key: Option<String>,
    /// Time limit, seconds (a large store takes minutes).
    #[arg(long, default_value_t = 3600)]
    timeout: u64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let url = format!("{}/v1/admin/backup", args.server.trim_end_matches('/'));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let (status, body) = runtime.block_on(async {
        let client = reqwest::Client::builder()
            .timeout(Duration::from_secs(args.timeout))
            .build()?;
        let mut request = client.post(&url);
        if let Some(key) = &args.api_key {
            request = request.bearer_auth(key);
        }
        let response = request.send().await?;
        Ok::<_, reqwest::Error>((response.status(), response.text().await?))
    })?;
    if !status.is_success() {
        bail!("{url} answers {status}: {body}");
    }
    println!("{body}");
    Ok(())
}

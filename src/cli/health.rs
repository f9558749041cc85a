//! `salient health [URL]`: exits 0 when the service's `/healthz` answers 200. The container's
//! `HEALTHCHECK` runs it, so the runtime image needs no curl.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::time::Duration;

use anyhow::{bail, Context};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Base URL of the service; default: the address `serve` listens on.
    url: Option<String>,
    /// The address `serve` listens on (an unspecified address such as 0.0.0.0 is checked on
    /// the loopback).
    #[arg(long, env = "SALIENT_ADDR", default_value = "127.0.0.1:8080")]
    addr: SocketAddr,
    /// Time limit, seconds.
    #[arg(long, default_value_t = 5)]
    timeout: u64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let base = args.url.unwrap_or_else(|| {
        let mut addr = args.addr;
        if addr.ip().is_unspecified() {
            addr.set_ip(IpAddr::V4(Ipv4Addr::LOCALHOST));
        }
        format!("http://{addr}")
    });
    let url = format!("{}/healthz", base.trim_end_matches('/'));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let status = runtime.block_on(async {
        reqwest::Client::builder()
            .timeout(Duration::from_secs(args.timeout))
            .build()?
            .get(&url)
            .send()
            .await
            .map(|r| r.status())
    });
    let status = status.with_context(|| format!("{url} does not answer"))?;
    if !status.is_success() {
        bail!("{url} answers {status}");
    }
    println!("ok");
    Ok(())
}

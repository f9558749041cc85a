//! `salient keys new`: makes an API key, prints it once, and adds its hash to a key file.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;

use salient_server::api::auth::{new_key, Scope};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Make a key: the key goes to stdout (shown this once), its hash to the key file.
    New {
        /// What the key allows: read, write (read + add, replace, delete) or admin.
        #[arg(long)]
        scope: String,
        /// A name for the key in logs and in the file (who holds it).
        #[arg(long)]
        label: String,
        /// The key file of `salient serve --keys` (created if missing); without it, the line
        /// for one is printed on stderr.
        #[arg(long)]
        file: Option<PathBuf>,
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let Command::New { scope, label, file } = args.command;
    let scope: Scope = scope.parse()?;
    anyhow::ensure!(
        !label.trim().is_empty() && !label.contains(['\n', '\r']),
        "the label must be one non-empty line"
    );
    let (key, line) = new_key(scope, label.trim());
    match &file {
        Some(path) => {
            let mut options = std::fs::OpenOptions::new();
            options.create(true).append(true);
            #[cfg(unix)]
            std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
            let mut out = options
                .open(path)
                .with_context(|| format!("cannot open the key file {}", path.display()))?;
            writeln!(out, "{line}")
                .with_context(|| format!("cannot write the key file {}", path.display()))?;
            eprintln!(
                "added a {scope} key to {}; send SIGHUP to a running server to accept it",
                path.display()
            );
        }
        None => eprintln!("key file line: {line}"),
    }
    println!("{key}");
    Ok(())
}

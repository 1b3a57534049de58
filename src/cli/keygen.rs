//! `afterimage keygen`: a new API key. The secret goes to the client (`--api-key`,
//! `AFTERIMAGE_API_KEY`); the server's keys file (`api_keys_file`) gets only its SHA-256.

use afterimage::session::access::{hash_hex, new_secret};
use clap::Args;

/// Arguments of `keygen`.
#[derive(Args, Debug)]
pub struct KeygenArgs {
    /// The key's name (in logs and quota messages): 1-64 printable characters, no spaces.
    #[arg(long)]
    name: String,
    /// Sessions the key may hold open at once (default: the server's max_sessions).
    #[arg(long)]
    max_sessions: Option<usize>,
    /// Memory the key's sessions and requests may hold, MiB (default: the server's budget).
    #[arg(long)]
    memory_mib: Option<u64>,
}

pub fn run(args: KeygenArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        !args.name.is_empty() && args.name.len() <= 64 && args.name.chars().all(|c| c.is_ascii_graphic()),
        "--name: expected 1-64 printable ASCII characters without spaces, got {:?}",
        args.name
    );
    let secret = new_secret()?;
    let mut entry = format!(
        "[[key]]\nname = \"{}\"\nsha256 = \"{}\"\n",
        args.name,
        hash_hex(&secret)
    );
    if let Some(n) = args.max_sessions {
        entry += &format!("max_sessions = {n}\n");
    }
    if let Some(m) = args.memory_mib {
        entry += &format!("memory_mib = {m}\n");
    }
    super::print_stdout(&format!(
        "# The client's secret (pass it as --api-key or AFTERIMAGE_API_KEY; it is not stored anywhere):\n# {secret}\n# The server's keys file entry:\n{entry}"
    ))
}

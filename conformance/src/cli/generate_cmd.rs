//! Man pages and shell completions, generated from the clap definitions by the binary
//! itself, so they cannot drift from the options it takes: `conformance completions
//! SHELL` for a user, and the hidden `conformance generate man|completions DIR` that
//! `scripts/package` runs to put them in the packages.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, CommandFactory, Subcommand};
use clap_complete::Shell;

use super::Cli;

/// Arguments of `conformance completions`.
#[derive(Debug, Args)]
#[command(after_help = "\
Examples:
  conformance completions bash > ~/.local/share/bash-completion/completions/conformance
  conformance completions zsh > ~/.zfunc/_conformance     # with fpath+=~/.zfunc in ~/.zshrc
  conformance completions fish > ~/.config/fish/completions/conformance.fish

The Debian package installs them for bash, zsh and fish already.")]
pub struct CompletionsArgs {
    /// The shell to complete for.
    #[arg(value_enum)]
    shell: Shell,
}

/// Arguments of the hidden `conformance generate`.
#[derive(Debug, Args)]
pub struct GenerateArgs {
    #[command(subcommand)]
    what: What,
}

#[derive(Debug, Subcommand)]
enum What {
    /// A man page for the command and one for every subcommand (conformance-check.1, ...).
    Man {
        /// The folder to write them to (made if missing).
        dir: PathBuf,
    },
    /// The completion scripts for bash, zsh and fish, under the names each shell looks
    /// for (conformance.bash, _conformance, conformance.fish).
    Completions {
        /// The folder to write them to (made if missing).
        dir: PathBuf,
    },
}

/// The shells the packages carry completions for.
const PACKAGED: [Shell; 3] = [Shell::Bash, Shell::Zsh, Shell::Fish];

/// Runs `conformance completions SHELL`: the script on stdout.
pub fn completions(args: CompletionsArgs) -> anyhow::Result<ExitCode> {
    clap_complete::generate(
        args.shell,
        &mut Cli::command(),
        "conformance",
        &mut std::io::stdout(),
    );
    Ok(ExitCode::SUCCESS)
}

/// Runs `conformance generate man|completions DIR`.
pub fn generate(args: GenerateArgs) -> anyhow::Result<ExitCode> {
    let (What::Man { dir } | What::Completions { dir }) = &args.what;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot make {}", dir.display()))?;
    let written = match &args.what {
        What::Man { dir } => man(dir)?,
        What::Completions { dir } => {
            let mut n = 0;
            for shell in PACKAGED {
                clap_complete::generate_to(shell, &mut Cli::command(), "conformance", dir)
                    .with_context(|| format!("cannot write the {shell} completions"))?;
                n += 1;
            }
            n
        }
    };
    println!("{written} files written under {}", dir.display());
    Ok(ExitCode::SUCCESS)
}

/// Writes the man pages into `dir`; how many.
fn man(dir: &Path) -> anyhow::Result<usize> {
    clap_mangen::generate_to(Cli::command(), dir)
        .with_context(|| format!("cannot write the man pages into {}", dir.display()))?;
    Ok(std::fs::read_dir(dir)?
        .flatten()
        .filter(|e| e.path().extension().is_some_and(|x| x == "1"))
        .count())
}

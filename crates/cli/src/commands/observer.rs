//! `fishprobe live biotracker`: fishprobe as a BioTracker v4 observer component. BioTracker's
//! core starts it (through `lab/biotracker/fishprobe_biotracker.py`), sets
//! `BIOTRACKER_COMPONENT_ADDRESS`, and calls it over gRPC; the robot program reads the robot
//! sink. Everything it says goes to its log file, never to stdout or stderr (pipes into the
//! core's log, which fail once the core is gone).

use anyhow::{bail, Context, Result};
use clap::Args;
use fishprobe_live::biotracker::component::{self, ComponentGuard, Prepared};
use fishprobe_live::biotracker::ObserverSettings;
use fishprobe_live::LiveError;
use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// The environment variable in which BioTracker's core passes a component its address.
pub const ADDRESS_VAR: &str = "BIOTRACKER_COMPONENT_ADDRESS";

/// Exit status when the component ends for any reason but a requested stop (the core gone,
/// the server failing): non-zero, so a supervisor sees it.
const EXIT_ENDED: i32 = 3;

#[derive(Debug, Args)]
pub(super) struct BiotrackerArgs {
    /// Address to serve the observer on (default: `$BIOTRACKER_COMPONENT_ADDRESS`, which the
    /// core sets); loopback only.
    #[arg(long)]
    address: Option<SocketAddr>,
    /// The core's address for the heartbeat until the component's config names one.
    #[arg(long, default_value = "127.0.0.1:27342")]
    core: SocketAddr,
    /// The component's log file (appended to).
    #[arg(long, default_value = "fishprobe-biotracker.log")]
    log: PathBuf,
}

/// What a config entry names, loaded and checked: the protocol settings (`fish_count` from
/// the fish ids) and the policy, which must fit them.
fn load(s: &ObserverSettings) -> Result<Prepared, LiveError> {
    let settings = |e: anyhow::Error| LiveError::Settings(format!("{e:#}"));
    let mut live = super::live_settings(s.config.as_deref()).map_err(settings)?;
    live.fish_count = u32::try_from(s.fish_ids.len()).unwrap_or(u32::MAX);
    live.validate()?;
    let mut make = super::pilot(&s.policy, &live).map_err(settings)?;
    let default_hz = fishprobe_sim::EnvConfig::default().frame_rate_hz;
    let trained_fps = make()
        .ok()
        .and_then(|c| c.trained_frame_rate_hz())
        .unwrap_or(default_hz);
    Ok(Prepared {
        live,
        task: fishprobe_sim::TaskParams::default(),
        trained_fps,
        pilot: Box::new(make),
    })
}

pub(super) fn run(a: BiotrackerArgs) -> Result<()> {
    let address = match a.address {
        Some(x) => x,
        None => {
            let v = std::env::var(ADDRESS_VAR).with_context(|| {
                format!("no --address and no {ADDRESS_VAR} (BioTracker's core sets it when it starts a component)")
            })?;
            v.trim()
                .parse()
                .with_context(|| format!("{ADDRESS_VAR} = {v:?} is not an address"))?
        }
    };
    if !address.ip().is_loopback() {
        bail!("the observer serves on loopback only (the tracker core runs on this machine; gRPC here has no authentication): {address}");
    }
    let listener =
        TcpListener::bind(address).with_context(|| format!("serving the observer on {address}"))?;
    let stop = Arc::new(AtomicBool::new(false));
    fishprobe_live::shutdown::install()?;
    let end = component::run(
        listener,
        a.core,
        Box::new(load),
        ComponentGuard::default(),
        Some(a.log.clone()),
        None,
        stop,
    )
    .with_context(|| format!("the observer component (log: {})", a.log.display()))?;
    // The core may be gone with its pipes: the log has said everything; only the status
    // remains to be told.
    if let Some(code) = fishprobe_live::shutdown::exit_status() {
        std::process::exit(code)
    } else if end.reason == "stopped" && end.unsaved.is_empty() {
        Ok(())
    } else {
        std::process::exit(EXIT_ENDED)
    }
}

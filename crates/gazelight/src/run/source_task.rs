//! The source side of a live session: the URI is parsed and opened by
//! `gazelight-tracker` (the one parser, the one `open`, for every scheme:
//! `pupil://`, `replay://PATH[?speed=S]`, `synthetic://demo`, `lsl://…`,
//! `hid://`, `usb://`, `serial://`, `gazepoint://`), and its live eye task
//! (the one place samples are filtered, with the stale → model fallback
//! and the source status) feeds the [`Hub`]. This module only prepares what
//! the tracker cannot know — the demo trace for the session's view — and
//! wires the task's channels into the hub.

use std::sync::Arc;

use anyhow::Context;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::live::LiveConfig;
use gazelight_tracker::live_events::EventQueue;
use gazelight_tracker::lsl::LslConfig;
use gazelight_tracker::transport::{self, OpenOptions, SourceUri};
use gazelight_vision::RgbImage;
use gazelight_vision::scene::ViewParams;
use tokio::task::JoinHandle;

use crate::demo;
use crate::hub::Hub;

use gazelight_tracker::live::{AdaptationCell, AgeClock};

/// A running source: the hub it feeds and the task behind it.
pub struct SourceHandle {
    pub hub: Arc<Hub>,
    pub age_clock: AgeClock,
    pub adaptation: Arc<AdaptationCell>,
    pub tasks: Vec<JoinHandle<()>>,
    /// One line for the log.
    pub describe: String,
}

/// What a synthetic source needs from the session: the view it runs on.
pub struct DemoContext<'a> {
    pub view: &'a ViewParams,
    pub view_img: &'a RgbImage,
}

/// Opens the source named by `uri` with the session's `[lsl]` settings and
/// starts its live eye task; the events it carries (Pupil Capture's
/// annotations) go to `events` when given. Must be called inside a tokio
/// runtime.
pub fn open_source_with(
    uri: &str,
    chain: FilterChain,
    demo_ctx: &DemoContext<'_>,
    lsl: &LslConfig,
    events: Option<Arc<EventQueue>>,
) -> anyhow::Result<SourceHandle> {
    let parsed = SourceUri::parse(uri)?;
    let synthetic = match &parsed {
        SourceUri::Synthetic { .. } => {
            let trace = demo::demo_trace(demo_ctx.view, demo_ctx.view_img)
                .with_context(|| format!("source `{uri}`"))?;
            Some((trace.samples, demo::DEMO_SECS))
        }
        _ => None,
    };
    let options = OpenOptions {
        lsl: lsl.clone(),
        synthetic,
        events,
    };
    let (shutdown_tx, shutdown_rx) = tokio::sync::watch::channel(false);
    let live = transport::open_live(
        uri,
        &parsed,
        &options,
        chain,
        shutdown_rx,
        LiveConfig::default(),
    )?;
    let hub = Hub::for_live(&live, shutdown_tx);
    Ok(SourceHandle {
        hub,
        age_clock: live.age_clock,
        adaptation: live.adaptation,
        tasks: vec![live.task],
        describe: live.describe,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx_view() -> (ViewParams, RgbImage) {
        let view = demo::default_view(32, 24);
        let img = RgbImage::new(view.width, view.height);
        (view, img)
    }

    #[tokio::test]
    async fn every_error_names_the_uri() {
        let (view, view_img) = ctx_view();
        let ctx = DemoContext {
            view: &view,
            view_img: &view_img,
        };
        for (uri, needle) in [
            ("nope", "SCHEME://"),
            ("ftp://x", "unknown scheme `ftp`"),
            ("replay://", "replay://PATH[?speed=S]"),
            ("replay://a?speed=0", "0 < speed ≤ 1000"),
            ("replay://a?x=1", "unknown parameter `x`"),
            (
                "synthetic://other",
                "the only synthetic source is synthetic://demo",
            ),
            ("pupil://h:x", "port"),
            (
                "replay:///nonexistent/gazelight.csv",
                "cannot open the recording",
            ),
        ] {
            let Err(e) = open_source_with(
                uri,
                FilterChain::with_defaults(),
                &ctx,
                &LslConfig::default(),
                None,
            ) else {
                panic!("{uri}: expected an error");
            };
            let e = format!("{e:#}");
            assert!(e.contains(uri), "{uri}: {e}");
            assert!(e.contains(needle), "{uri}: `{needle}` not in {e}");
        }
    }
}

//! Lab Streaming Layer: the inlets of `gazelight-devices`, and
//! [`summarize_lsl`], which reads a stream for a while and summarises it
//! like a recording (`gazelight inspect lsl://…`).

use std::time::Duration;

pub use gazelight_devices::lsl::*;
use gazelight_eye::filter::FilterChain;
use gazelight_eye::source::{SampleSource, SourceError};
use gazelight_import::ImportWarnings;
use gazelight_import::summary::{RecordingSummary, Summarizer};

/// Why an LSL summary failed.
#[derive(Debug, thiserror::Error)]
pub enum LslSummaryError {
    #[error(transparent)]
    Lsl(#[from] LslError),
    #[error("{0}")]
    Source(#[from] SourceError),
    #[error("no LSL stream {query} found within {secs:.1} s")]
    NotFound { query: String, secs: f64 },
}

/// Reads `query` for `duration` (from the first sample; waiting for the
/// stream is bounded by `duration` too), runs the samples through `chain`
/// and summarises them. The warnings name the stream, its layout and the
/// time correction.
pub async fn summarize_lsl(
    query: LslQuery,
    config: LslConfig,
    duration: Duration,
    chain: FilterChain,
) -> Result<(RecordingSummary, StreamFacts), LslSummaryError> {
    let mut source = LslSource::new(query.clone(), config)?;
    let mut summarizer = Summarizer::new(chain);
    let first = match tokio::time::timeout(duration + Duration::from_secs(2), source.next()).await {
        Ok(Ok(Some(s))) => s,
        Ok(Ok(None)) => {
            return Err(LslSummaryError::NotFound {
                query: query.to_string(),
                secs: duration.as_secs_f64(),
            });
        }
        Ok(Err(e)) => return Err(e.into()),
        Err(_) => {
            return Err(LslSummaryError::NotFound {
                query: query.to_string(),
                secs: duration.as_secs_f64() + 2.0,
            });
        }
    };
    summarizer.push(&first);
    let deadline = tokio::time::Instant::now() + duration;
    let mut lost = 0u64;
    loop {
        match tokio::time::timeout_at(deadline, source.next()).await {
            Ok(Ok(Some(s))) => summarizer.push(&s),
            Ok(Ok(None)) => break,
            Ok(Err(SourceError::Disconnected { .. })) => lost += 1,
            Ok(Err(SourceError::Item { .. })) => {}
            Ok(Err(e)) => return Err(e.into()),
            Err(_) => break,
        }
    }
    let facts = source.facts();
    let mut warnings = ImportWarnings::default();
    warnings.messages.push(format!(
        "LSL stream `{}` (type {}, source_id `{}`, {} channels, {} Hz nominal), layout {}, time correction {:.6} s",
        facts.name,
        facts.kind,
        facts.source_id,
        facts.channels,
        facts.nominal_srate_hz,
        facts.layout.as_deref().unwrap_or("?"),
        facts.time_correction_s.unwrap_or(f64::NAN)
    ));
    if lost > 0 {
        warnings
            .messages
            .push(format!("the stream was lost {lost} time(s) while reading"));
    }
    Ok((summarizer.finish(Some("lsl"), &warnings), facts))
}

//! A summary of any live source (`inspect neon://…`, `inspect gazepoint://…`):
//! the samples of a fixed stretch of time through the filter chain, with
//! the source's bad items, losses and drops as counted warnings.

use std::time::Duration;

use gazelight_eye::filter::FilterChain;
use gazelight_eye::source::{SampleSource, SourceError};
use gazelight_import::summary::{RecordingSummary, Summarizer};
use gazelight_import::{ImportWarnings, KEPT_WARNING_MESSAGES};

/// Why a live summary failed.
#[derive(Debug, thiserror::Error)]
pub enum SourceSummaryError {
    /// No sample arrived within the wait for the first one.
    #[error("{source_name}: no sample within {after_secs:.1} s{}", last.as_deref().map(|l| format!(" (last error: {l})")).unwrap_or_default())]
    NoSample {
        source_name: String,
        after_secs: f64,
        last: Option<String>,
    },
    /// The source cannot continue.
    #[error(transparent)]
    Source(#[from] SourceError),
}

/// Collects `source` for `duration` from its first sample (waiting at most
/// `first_within` for it), runs the samples through `chain` and summarises
/// them as `format`. Bad items and losses are counted as skipped records
/// and named in the warnings (the first few); a source that ends early
/// ends the stretch. Memory is the summary's, whatever the duration.
pub async fn summarize_source<S: SampleSource>(
    source: &mut S,
    duration: Duration,
    first_within: Duration,
    chain: FilterChain,
    format: &'static str,
) -> Result<RecordingSummary, SourceSummaryError> {
    let mut summarizer = Summarizer::new(chain);
    let mut warnings = ImportWarnings::default();
    let mut deadline = tokio::time::Instant::now() + first_within;
    let mut started = false;
    let mut last_error: Option<String> = None;
    let mut losses = 0u64;
    loop {
        let next = match tokio::time::timeout_at(deadline, source.next()).await {
            Err(_) if !started => {
                return Err(SourceSummaryError::NoSample {
                    source_name: source.describe(),
                    after_secs: first_within.as_secs_f64(),
                    last: last_error,
                });
            }
            Err(_) => break,
            Ok(next) => next,
        };
        match next {
            Ok(Some(sample)) => {
                if !started {
                    started = true;
                    deadline = tokio::time::Instant::now() + duration;
                }
                summarizer.push(&sample);
            }
            Ok(None) => break,
            Err(e @ SourceError::Fatal { .. }) => return Err(e.into()),
            Err(e) => {
                if matches!(e, SourceError::Disconnected { .. }) {
                    losses += 1;
                }
                let text = e.to_string();
                warnings.skipped_records += 1;
                if warnings.messages.len() < KEPT_WARNING_MESSAGES {
                    warnings.messages.push(text.clone());
                }
                last_error = Some(text);
            }
        }
    }
    let dropped = source.dropped();
    if dropped > 0 {
        warnings.messages.push(format!(
            "{}: {dropped} samples dropped (consumer too slow)",
            source.describe()
        ));
    }
    if losses > 0 {
        warnings
            .messages
            .push(format!("{}: lost {losses} times", source.describe()));
    }
    Ok(summarizer.finish(Some(format), &warnings))
}

//! gazelight's application core: the rules the three front ends (the
//! `gazelight` CLI, the `gazelight` Python module and the OpenXR layer)
//! share, written once here so that they cannot drift apart. The front ends
//! only translate their inputs (flags, keyword arguments, a layer config)
//! into calls on it.
//!
//! Today it holds [`bounds`], the limits on every number a user gives
//! (rates, durations, frame counts, image sizes, luminance scales);
//! [`observer`], the observer's age and pigmentation and where they come
//! from; [`config`], the one configuration schema and loader of the CLI's
//! commands and Python's `render` (and the `[filter]` table Python's
//! `read`/`FilterChain` take alone); and [`layer_config`], the OpenXR
//! layer's `layer.toml`; and [`backend`], the renderer choice (`auto`,
//! `gpu`, `cpu`: the rule, the fallback and the GPU/CPU `Renderer` the
//! CLI's commands and Python's `render` drive); and [`session`], the
//! settings in effect with where each came from (`session.json`);
//! [`shutdown`], the signals that end a session with its outputs whole. The rest of the
//! application core (the render/replay session and its streaming per-frame
//! writer, source opening) is still in the binary crate and moves here
//! piece by piece (ARCHITECTURE.md, "Where the front ends still
//! differ").

pub mod backend;
pub mod bounds;
pub mod config;
pub mod layer_config;
pub mod observer;
pub mod session;
pub mod shutdown;

#[cfg(test)]
pub(crate) mod tests {
    /// An error and its sources, `outer: inner: …`, as the CLI prints it
    /// (anyhow's alternate format).
    pub(crate) use gazelight_output::error_chain as chain;
}

//! The Pupil-compatible relay (`run --relay`): the server is
//! [`gazelight_tracker::pupil::relay`]; this feeds it the session's hub.

use std::net::SocketAddr;
use std::sync::Arc;

use gazelight_tracker::LiveEyeState;
use gazelight_tracker::Sample;
use gazelight_tracker::pupil::relay::{FrameFigures, RelayError, RelayFeed, RelayHandle};
use tokio::sync::{broadcast, watch};

use crate::hub::Hub;

impl RelayFeed for Hub {
    fn eye(&self) -> watch::Receiver<LiveEyeState> {
        self.eye.clone()
    }

    fn subscribe_samples(&self) -> broadcast::Receiver<Sample> {
        self.samples.subscribe()
    }

    fn frame(&self) -> FrameFigures {
        let f = Hub::frame(self);
        FrameFigures {
            frames: f.frames,
            t_secs: f.t_secs,
            adaptation_cd_m2: f.adaptation_cd_m2,
            target_cd_m2: f.target_cd_m2,
            frame_pupil_mm: f.frame_pupil_mm,
            pupil_mm: f.pupil_mm,
            eye_state_age_ms: f.eye_state_age_ms,
            pupil_light_mm: f.pupil_light_mm,
            pupil_residual_mm: f.pupil_residual_mm,
        }
    }

    fn shutdown_signal(&self) -> watch::Receiver<bool> {
        Hub::shutdown_signal(self)
    }
}

/// Starts the relay on `remote_addr` over `hub` (see
/// [`gazelight_tracker::pupil::relay::spawn`]); it stops at the hub's shutdown.
pub async fn spawn(hub: Arc<Hub>, remote_addr: SocketAddr) -> Result<RelayHandle, RelayError> {
    gazelight_tracker::pupil::relay::spawn(hub, remote_addr).await
}

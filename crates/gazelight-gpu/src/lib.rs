//! The gazelight frame pipeline on wgpu compute passes.
//!
//! Not built yet: every stage currently runs on the CPU reference pipeline in
//! `gazelight-vision`. See the GPU pipeline issue.

// The uniforms of one glare-kernel build on the GPU (the twin of
// gazelight_gpu::psf::PsfBuild), shared by psf_aperture.wgsl,
// psf_intensity.wgsl, psf_spectral.wgsl and psf_normalise.wgsl, which run in
// that order (with gazelight_gpu::fft's forward FFT after the aperture) and
// mirror gazelight_vision::psf::PsfBuilder::rebuild step by step. Lengths
// are pupil-plane samples unless named otherwise.

struct PsfBuild {
    // Pupil-plane grid N (a power of two), kernel size 2r + 1, r, k + 1.
    n: u32,
    kernel_size: u32,
    kernel_radius: u32,
    wavelength_count: u32,
    // N / 2; pupil radius D / (2 Δx); the aperture's last non-zero ring
    // (radius + 1); defocus phase per sample², π ΔD Δx² / λ (001 eq 6
    // residual, radians).
    half: f32,
    r_samples: f32,
    edge: f32,
    defocus_rad_per_sample2: f32,
    // |FFT(L)|² → fraction of the light entering the pupil per sample:
    // 1 / (N² π r²) (001 eq 8 times (λd)² / (π r²)).
    intensity_scale: f32,
    // Radius of the wave-optics region, display pixels.
    near_radius_px: f32,
    // σ_p · Ω_px (particle lobes beyond the near region; 0 = none), entries
    // of the lobe table and its entries per display pixel of radius.
    lobe_scale: f32,
    lobe_count: u32,
    lobe_per_px: f32,
    // 1 − Σ CIE 146 term: the near field's share of the unit energy.
    budget: f32,
    _pad0: u32,
    _pad1: u32,
}

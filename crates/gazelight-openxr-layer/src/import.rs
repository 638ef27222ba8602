//! The app's image into the frame pipeline's scene buffer
//! (`shaders/layer_import.wgsl`) and its CPU twin [`import_cpu`].
//!
//! The swapchain image's texels are copied into a buffer (rows padded to
//! 256 bytes, a texture copy's alignment); one compute pass decodes them to
//! linear RGB in cd/m²: 8-bit sRGB codes through the 256-entry table of
//! [`gazelight_vision::tone::srgb_to_linear`], times `white_cd_m2`;
//! half floats times `scene_scale_cd_m2`.

use bytemuck::{Pod, Zeroable};
use gazelight_gpu::GpuContext;
use gazelight_gpu::GpuError;
use gazelight_gpu::pass::{Binding, PassDescriptor, PassLayout};
use gazelight_gpu::shaders::WgslShader;

/// The texel layouts the import reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// `R8G8B8A8_SRGB`.
    Rgba8Srgb,
    /// `B8G8R8A8_SRGB`.
    Bgra8Srgb,
    /// `R16G16B16A16_SFLOAT`.
    Rgba16Float,
}

impl ImageFormat {
    /// The layout of a wgpu texture format, when served.
    pub fn of(format: wgpu::TextureFormat) -> Option<Self> {
        match format {
            wgpu::TextureFormat::Rgba8UnormSrgb => Some(Self::Rgba8Srgb),
            wgpu::TextureFormat::Bgra8UnormSrgb => Some(Self::Bgra8Srgb),
            wgpu::TextureFormat::Rgba16Float => Some(Self::Rgba16Float),
            _ => None,
        }
    }

    /// Bytes per texel.
    pub fn texel_bytes(self) -> u32 {
        match self {
            Self::Rgba8Srgb | Self::Bgra8Srgb => 4,
            Self::Rgba16Float => 8,
        }
    }

    fn code(self) -> u32 {
        match self {
            Self::Rgba8Srgb => 0,
            Self::Bgra8Srgb => 1,
            Self::Rgba16Float => 2,
        }
    }
}

/// Bytes per padded row of a `width`-texel copy.
pub fn row_bytes(format: ImageFormat, width: u32) -> u32 {
    (width * format.texel_bytes()).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
        * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT
}

/// The linear values of the 256 sRGB codes (the CPU's decoding).
pub fn srgb_table() -> [f32; 256] {
    std::array::from_fn(|i| gazelight_vision::tone::srgb_to_linear(i as f32 / 255.0))
}

/// IEEE 754 binary16 → f32 (exact).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0f32 } else { 1.0 };
    let exp = i32::from((h >> 10) & 0x1f);
    let frac = f32::from(h & 0x3ff);
    match exp {
        0 => sign * frac * 2f32.powi(-24),
        31 if frac == 0.0 => sign * f32::INFINITY,
        31 => f32::NAN,
        _ => sign * (1.0 + frac / 1024.0) * 2f32.powi(exp - 15),
    }
}

/// The CPU twin of the import pass: `texels` (rows of `row_bytes` bytes)
/// of a `width × height` image into linear RGB, cd/m², alpha 0.
pub fn import_cpu(
    texels: &[u8],
    row_bytes: usize,
    width: usize,
    height: usize,
    format: ImageFormat,
    scale: f32,
) -> Option<Vec<[f32; 4]>> {
    let tb = format.texel_bytes() as usize;
    if row_bytes < width * tb || texels.len() < row_bytes * height.saturating_sub(1) + width * tb {
        return None;
    }
    let lut = srgb_table();
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let t = &texels[y * row_bytes + x * tb..][..tb];
            let rgb = match format {
                ImageFormat::Rgba8Srgb => [t[0], t[1], t[2]].map(|c| lut[usize::from(c)]),
                ImageFormat::Bgra8Srgb => [t[2], t[1], t[0]].map(|c| lut[usize::from(c)]),
                ImageFormat::Rgba16Float => {
                    [0, 2, 4].map(|k| f16_to_f32(u16::from_le_bytes([t[k], t[k + 1]])))
                }
            };
            out.push([rgb[0] * scale, rgb[1] * scale, rgb[2] * scale, 0.0]);
        }
    }
    Some(out)
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct ImportParams {
    width: u32,
    height: u32,
    row_words: u32,
    format: u32,
    scale: f32,
    _pad: [u32; 3],
}

static IMPORT_SHADER: WgslShader = WgslShader {
    name: "layer_import.wgsl",
    source: include_str!("../shaders/layer_import.wgsl"),
};

static IMPORT_PASS: PassDescriptor = PassDescriptor {
    shader: IMPORT_SHADER,
    entry_points: &["import_image"],
    bindings: &[
        Binding::uniform::<ImportParams>("params"),
        Binding::read::<u32>("texels"),
        Binding::read::<f32>("lut"),
        Binding::read_write::<[f32; 4]>("scene"),
    ],
};

/// The import pass of one eye's image size and format, writing into a
/// pipeline's scene buffer.
pub struct ImportPass {
    pipeline: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    texels: wgpu::Buffer,
    format: ImageFormat,
    width: u32,
    height: u32,
    row_bytes: u32,
    _layout: PassLayout,
}

impl ImportPass {
    /// For `width × height` images of `format`, into `scene` (`width·height`
    /// RGBA f32, `STORAGE` usage).
    pub fn new(
        ctx: &GpuContext,
        format: ImageFormat,
        width: u32,
        height: u32,
        scale: f32,
        scene: &wgpu::Buffer,
    ) -> Result<Self, GpuError> {
        let (layout, [pipeline]) = IMPORT_PASS.build::<1>(ctx)?;
        let row_bytes = row_bytes(format, width);
        let device = ctx.device();
        let texels = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gazelight-layer texels"),
            size: u64::from(row_bytes) * u64::from(height),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let params = ImportParams {
            width,
            height,
            row_words: row_bytes / 4,
            format: format.code(),
            scale,
            _pad: [0; 3],
        };
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gazelight-layer import params"),
            size: size_of::<ImportParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue()
            .write_buffer(&uniform, 0, bytemuck::bytes_of(&params));
        let lut = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gazelight-layer sRGB table"),
            size: 256 * 4,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue()
            .write_buffer(&lut, 0, bytemuck::cast_slice(&srgb_table()));
        let group = layout.bind_buffers(ctx, &[&uniform, &texels, &lut, scene])?;
        Ok(Self {
            pipeline,
            group,
            texels,
            format,
            width,
            height,
            row_bytes,
            _layout: layout,
        })
    }

    /// Records the copy of `texture`'s `layer` at `origin` and the decode.
    pub fn encode(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        texture: &wgpu::Texture,
        layer: u32,
        origin: [u32; 2],
        timestamps: Option<(&wgpu::QuerySet, u32)>,
    ) {
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: 0,
                origin: wgpu::Origin3d {
                    x: origin[0],
                    y: origin[1],
                    z: layer,
                },
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &self.texels,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.row_bytes),
                    rows_per_image: Some(self.height),
                },
            },
            wgpu::Extent3d {
                width: self.width,
                height: self.height,
                depth_or_array_layers: 1,
            },
        );
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("gazelight-layer import"),
            timestamp_writes: timestamps.map(|(q, i)| wgpu::ComputePassTimestampWrites {
                query_set: q,
                beginning_of_pass_write_index: Some(i),
                end_of_pass_write_index: Some(i + 1),
            }),
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.group, &[]);
        pass.dispatch_workgroups(self.width.div_ceil(8), self.height.div_ceil(8), 1);
    }

    /// The texel layout.
    pub fn format(&self) -> ImageFormat {
        self.format
    }

    /// The texel buffer (tests read it back).
    pub fn texels(&self) -> &wgpu::Buffer {
        &self.texels
    }

    /// Bytes per padded row in [`Self::texels`].
    pub fn row_bytes(&self) -> u32 {
        self.row_bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_floats_decode_exactly() {
        // IEEE 754 binary16 test values (bit patterns from the standard's
        // layout: sign, 5-bit exponent biased by 15, 10-bit fraction).
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert_eq!(f16_to_f32(0x3555), 0.333_251_95);
        assert!(f16_to_f32(0x7c00).is_infinite());
        assert!(f16_to_f32(0x7e00).is_nan());
    }

    #[test]
    fn srgb_codes_decode_to_the_iec_values() {
        // IEC 61966-2-1: code 128 → ((128/255 + 0.055)/1.055)^2.4 = 0.21586.
        let t = srgb_table();
        assert_eq!(t[0], 0.0);
        assert!((t[255] - 1.0).abs() < 1e-6);
        assert!((t[128] - 0.215_86).abs() < 1e-4, "{}", t[128]);
        let px = import_cpu(&[128, 0, 255, 9], 4, 1, 1, ImageFormat::Bgra8Srgb, 100.0)
            .unwrap_or_default();
        assert!((px[0][0] - 100.0).abs() < 1e-3 && px[0][1] == 0.0, "{px:?}");
    }
}

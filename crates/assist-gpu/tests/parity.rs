//! The GPU kernels against the CPU reference (`assist-field`), on whatever adapter is
//! present: lavapipe (Mesa's software Vulkan) in CI, a real card elsewhere. Without any
//! adapter the tests skip loudly, unless `ASSIST_REQUIRE_GPU=1` (CI sets it) makes that a
//! failure.

mod common;

use assist_core::Rng;
use assist_field::{Field, Samples};
use assist_gpu::{DeviceChoice, Gpu, GpuField};
use common::{configs, gpu, random_field};

struct Batch {
    pos: [Vec<f32>; 3],
    dir: [Vec<f32>; 3],
    image: Vec<u32>,
}

/// `n` samples: positions mostly in [0, 1]³ with a few outside (clamped by both), unit
/// directions, codes of every image and the average (`u32::MAX`).
fn batch(n: usize, images: usize, seed: u64) -> Batch {
    let mut rng = Rng::new(seed);
    let mut b = Batch {
        pos: Default::default(),
        dir: Default::default(),
        image: Vec::new(),
    };
    for i in 0..n {
        for a in 0..3 {
            b.pos[a].push(rng.f32() * 1.1 - 0.05);
        }
        let d = [rng.normal(), rng.normal(), rng.normal()];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        for a in 0..3 {
            b.dir[a].push((d[a] / len) as f32);
        }
        b.image.push(if i % 5 == 0 {
            u32::MAX
        } else {
            rng.below(images as u64) as u32
        });
    }
    b
}

fn samples(b: &Batch) -> Samples<'_> {
    Samples {
        pos: [&b.pos[0], &b.pos[1], &b.pos[2]],
        dir: [&b.dir[0], &b.dir[1], &b.dir[2]],
        image: &b.image,
    }
}

/// Largest |gpu − cpu| / (|cpu| + floor) over the outputs.
fn worst(gpu: &[f32], cpu: &[f32], floor: f32) -> f32 {
    assert_eq!(gpu.len(), cpu.len());
    gpu.iter()
        .zip(cpu)
        .map(|(g, c)| {
            assert!(g.is_finite(), "GPU output not finite: {g}");
            (g - c).abs() / (c.abs() + floor)
        })
        .fold(0.0, f32::max)
}

#[test]
fn forward_matches_cpu() {
    let Some(gpu) = gpu() else { return };
    for (seed, (name, cfg)) in configs().into_iter().enumerate() {
        let images = cfg.num_images.max(1);
        let field = random_field(cfg, seed as u64 + 1);
        let b = batch(3001, images, 11 + seed as u64);
        let s = samples(&b);
        let n = s.len();
        let (mut sig_c, mut rgb_c) = (vec![0.0; n], vec![0.0; 3 * n]);
        field.forward(&s, &mut sig_c, &mut rgb_c);
        let mut gf = GpuField::new(&gpu, &field).expect("upload");
        let (mut sig_g, mut rgb_g) = (vec![0.0; n], vec![0.0; 3 * n]);
        gf.forward(&gpu, &s, &mut sig_g, &mut rgb_g)
            .expect("forward");
        let (ws, wc) = (worst(&sig_g, &sig_c, 1e-3), worst(&rgb_g, &rgb_c, 1e-3));
        eprintln!("{name}: worst relative difference σ {ws:.2e}, rgb {wc:.2e}");
        // f32 sums in another order and another exp: a few ulp per layer.
        assert!(ws < 1e-4 && wc < 1e-4, "{name}: σ {ws:e}, rgb {wc:e}");
        // The outputs vary (a kernel that wrote constants would pass the bound above only
        // if the CPU did too).
        let spread = sig_c
            .iter()
            .fold(0.0f32, |m, &v| m.max((v - sig_c[0]).abs()));
        assert!(spread > 1e-2, "{name}: σ barely varies ({spread})");

        // Density alone, as the occupancy refresh asks for it.
        let mut dens_c = vec![0.0; n];
        field.density([&b.pos[0], &b.pos[1], &b.pos[2]], &mut dens_c);
        let mut dens_g = vec![0.0; n];
        gf.density(&gpu, [&b.pos[0], &b.pos[1], &b.pos[2]], &mut dens_g)
            .expect("density");
        let wd = worst(&dens_g, &dens_c, 1e-3);
        assert!(wd < 1e-4, "{name}: density {wd:e}");
        assert!(
            worst(&dens_g, &sig_g, 1e-3) < 1e-6,
            "{name}: density ≠ forward's σ"
        );
    }
}

#[test]
fn every_tile_size_gives_the_same_outputs() {
    let Some(gpu) = gpu() else { return };
    let (_, cfg) = configs().remove(0);
    let field = random_field(cfg, 4);
    let b = batch(1000, field.config.num_images, 9);
    let s = samples(&b);
    let (mut sig_c, mut rgb_c) = (vec![0.0; 1000], vec![0.0; 3000]);
    field.forward(&s, &mut sig_c, &mut rgb_c);
    for tile in [16, 32, 64] {
        let mut gf = GpuField::with_tile(&gpu, &field, Some(tile)).expect("upload");
        let (mut sig_g, mut rgb_g) = (vec![0.0; 1000], vec![0.0; 3000]);
        gf.forward(&gpu, &s, &mut sig_g, &mut rgb_g)
            .expect("forward");
        assert!(worst(&sig_g, &sig_c, 1e-3) < 1e-4, "tile {tile}");
        assert!(worst(&rgb_g, &rgb_c, 1e-3) < 1e-4, "tile {tile}");
    }
    assert!(GpuField::with_tile(&gpu, &field, Some(48)).is_err());
}

#[test]
fn new_parameters_are_used_after_upload() {
    let Some(gpu) = gpu() else { return };
    let (_, cfg) = configs().remove(0);
    let mut field = random_field(cfg, 3);
    let b = batch(500, field.config.num_images, 5);
    let s = samples(&b);
    let mut gf = GpuField::new(&gpu, &field).expect("upload");
    // Change the grid, the nets and the codes, then upload.
    for p in field.params.iter_mut().step_by(3) {
        *p *= -0.7;
    }
    gf.upload(&gpu, &field).expect("upload");
    let (mut sig_c, mut rgb_c) = (vec![0.0; 500], vec![0.0; 1500]);
    field.forward(&s, &mut sig_c, &mut rgb_c);
    let (mut sig_g, mut rgb_g) = (vec![0.0; 500], vec![0.0; 1500]);
    gf.forward(&gpu, &s, &mut sig_g, &mut rgb_g)
        .expect("forward");
    assert!(worst(&sig_g, &sig_c, 1e-3) < 1e-4);
    assert!(worst(&rgb_g, &rgb_c, 1e-3) < 1e-4);
    // A field of another size is refused, not silently misread.
    let other = Field::new(configs().remove(1).1, 1).expect("config");
    assert!(gf.upload(&gpu, &other).is_err());
}

/// A field whose colour follows the reflected direction (`FieldConfig::reflect`), which
/// no kernel computes, is refused with a message that says so, not run as another field.
#[test]
fn a_reflected_field_is_refused() {
    let Some(gpu) = gpu() else { return };
    let (_, mut cfg) = configs().remove(0);
    cfg.reflect = true;
    let field = random_field(cfg, 3);
    let err = GpuField::new(&gpu, &field)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("reflected") && err.contains("--device cpu"),
        "{err}"
    );
}

#[test]
fn cpu_choice_opens_nothing_and_auto_skips_software_adapters() {
    assert!(Gpu::open(DeviceChoice::Cpu).expect("cpu").is_none());
    if let Some(g) = Gpu::open(DeviceChoice::Auto).expect("auto") {
        assert_ne!(g.info.device_type, wgpu::DeviceType::Cpu, "{}", g.name());
    }
    assert!("gpu".parse::<DeviceChoice>().is_ok());
    let e = "cuda".parse::<DeviceChoice>().unwrap_err().to_string();
    assert!(e.contains("auto, cpu or gpu") && e.contains("cuda"), "{e}");
}

#[test]
fn a_batch_larger_than_a_binding_is_refused_by_size() {
    let Some(gpu) = gpu() else { return };
    let field = Field::new(configs().remove(0).1, 1).expect("config");
    // Features take 4 · L · F bytes per sample, the widest per-sample buffer here.
    let per = 4 * field.config.encoding_width() as u64;
    let n = (gpu.limits.max_storage_buffer_binding_size / per) as usize + 1;
    if n > 1 << 23 {
        eprintln!("SKIPPED: this adapter's bindings take {n} samples; too many to make here");
        return;
    }
    let zeros = vec![0.5f32; n];
    let s = Samples {
        pos: [&zeros, &zeros, &zeros],
        dir: [&[], &[], &[]],
        image: &[],
    };
    let mut gf = GpuField::new(&gpu, &field).expect("upload");
    let e = gf.load(&gpu, &s).unwrap_err().to_string();
    assert!(
        e.contains(&format!("{n} samples")) && e.contains("smaller batch"),
        "{e}"
    );
    // The field still works at a size that fits.
    let few = Samples {
        pos: [&zeros[..100], &zeros[..100], &zeros[..100]],
        dir: [&[], &[], &[]],
        image: &[],
    };
    let mut sigma = vec![0.0; 100];
    gf.density(&gpu, few.pos, &mut sigma).expect("density");
    assert!(sigma.iter().all(|v| v.is_finite() && *v > 0.0));
}

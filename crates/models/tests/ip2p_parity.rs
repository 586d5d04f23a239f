//! InstructPix2Pix parity with diffusers on tiny random components
//! (fixtures by tools/model_fixtures_ip2p.py): UNet forward (fp16 weights), VAE encode
//! mode and decode (fp32 weights), DDIM timesteps/steps/noising, and one whole 3-step
//! edit with three-way guidance. Tolerance: max |rust − ref| ≤ 1e-4 · max |ref|.

use std::collections::HashMap;
use std::path::PathBuf;

use candle_core::{Device, Tensor};
use transsplat_models::ip2p::{Ip2p, PromptEmbeds, Settings, DOWNLOAD_HINT};
use transsplat_models::ModelDir;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ip2p")
}

fn reference() -> HashMap<String, Tensor> {
    candle_core::safetensors::load(fixtures().join("reference.safetensors"), &Device::Cpu).unwrap()
}

fn pipeline() -> Ip2p {
    let dir = ModelDir::open(&fixtures(), "InstructPix2Pix", DOWNLOAD_HINT).unwrap();
    Ip2p::load(&dir, &Device::Cpu).unwrap()
}

/// Asserts max |a − b| ≤ 1e-4 · max |b| (and equal shapes).
fn assert_close(name: &str, a: &Tensor, b: &Tensor) {
    assert_eq!(a.dims(), b.dims(), "{name}: shape");
    let a: Vec<f32> = a.flatten_all().unwrap().to_vec1().unwrap();
    let b: Vec<f32> = b.flatten_all().unwrap().to_vec1().unwrap();
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
    let err = a.iter().zip(&b).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(scale > 0.0, "{name}: reference is all zeros");
    assert!(err <= 1e-4 * scale, "{name}: max error {err:e} vs scale {scale:e}");
}

fn scalar(r: &HashMap<String, Tensor>, k: &str) -> f32 {
    r[k].to_vec1::<f32>().unwrap()[0]
}

#[test]
fn unet_forward_matches_diffusers() {
    let r = reference();
    let p = pipeline();
    let t = scalar(&r, "unet.timestep") as f64;
    let out = p.unet.forward(&r["unet.sample"], t, &r["unet.encoder_hidden_states"]).unwrap();
    assert_close("unet", &out, &r["unet.out"]);
}

#[test]
fn vae_encode_mode_and_decode_match_diffusers() {
    let r = reference();
    let p = pipeline();
    assert_close("vae mode", &p.encode(&r["vae.image"]).unwrap(), &r["vae.mode"]);
    assert_close("vae decode", &p.vae.decode(&r["vae.latent"]).unwrap(), &r["vae.decoded"]);
}

#[test]
fn ddim_matches_diffusers() {
    let r = reference();
    let p = pipeline();
    for span in [700usize, 853, 980] {
        let ts = p.ddim.timesteps(span, 20).unwrap();
        let want: Vec<usize> = r[&format!("ddim.timesteps_{span}")]
            .to_vec1::<f32>()
            .unwrap()
            .iter()
            .map(|&t| t as usize)
            .collect();
        assert_eq!(ts, want, "timesteps for span {span}");
    }
    let ts = p.ddim.timesteps(853, 20).unwrap();
    let (x, eps) = (&r["ddim.sample"], &r["ddim.eps"]);
    for t in [ts[0], ts[10], ts[19]] {
        let got = p.ddim.step(eps, t, 853 / 20, x).unwrap();
        assert_close(&format!("ddim step t={t}"), &got, &r[&format!("ddim.step_853_{t}")]);
    }
    assert_close("add_noise", &p.ddim.add_noise(x, eps, ts[0]).unwrap(), &r["ddim.add_noise_853"]);
    assert!(p.ddim.timesteps(10, 20).is_err() && p.ddim.timesteps(1001, 20).is_err());
}

#[test]
fn whole_edit_matches_diffusers() {
    let r = reference();
    let p = pipeline();
    let settings = Settings { steps: scalar(&r, "edit.steps") as usize, ..Settings::default() };
    let span = scalar(&r, "edit.span") as usize;
    let want: Vec<usize> =
        r["edit.timesteps"].to_vec1::<f32>().unwrap().iter().map(|&t| t as usize).collect();
    assert_eq!(p.ddim.timesteps(span, settings.steps).unwrap(), want);
    let prompt =
        PromptEmbeds { cond: r["edit.prompt_embeds"].clone(), uncond: r["edit.uncond_embeds"].clone() };
    let mut calls = 0;
    let edit = p
        .edit(&r["edit.image"], &prompt, &r["edit.noise"], &[span], &settings, &mut |i, n| {
            calls += 1;
            assert_eq!((i, n), (calls, settings.steps));
            true
        })
        .unwrap();
    assert_eq!(calls, settings.steps);
    assert_close("edit attention", &edit.attention, &r["edit.attention"]);
    assert_close("edit image", &edit.image, &r["edit.edited"]);
}

/// Several images in one call (the batch the editor makes of a shard's views) give each
/// image's edit alone: the fixture's image at its span, and the same image mirrored with
/// other noise at another span.
#[test]
fn a_batch_of_images_edits_each_as_alone() {
    let r = reference();
    let p = pipeline();
    let settings = Settings { steps: scalar(&r, "edit.steps") as usize, ..Settings::default() };
    let span = scalar(&r, "edit.span") as usize;
    let prompt =
        PromptEmbeds { cond: r["edit.prompt_embeds"].clone(), uncond: r["edit.uncond_embeds"].clone() };
    let image = &r["edit.image"];
    let noise = &r["edit.noise"];
    let mirrored = image.flip(&[3]).unwrap();
    let other_noise = (noise.flip(&[2]).unwrap() * -1.0).unwrap();
    let other_span = span + settings.steps;
    let alone = |img: &Tensor, n: &Tensor, s: usize| {
        p.edit(img, &prompt, n, &[s], &settings, &mut |_, _| true).unwrap()
    };
    let (a, b) = (alone(image, noise, span), alone(&mirrored, &other_noise, other_span));
    let both = p
        .edit(
            &Tensor::cat(&[image, &mirrored], 0).unwrap(),
            &prompt,
            &Tensor::cat(&[noise, &other_noise], 0).unwrap(),
            &[span, other_span],
            &settings,
            &mut |_, _| true,
        )
        .unwrap();
    for (k, one) in [a, b].iter().enumerate() {
        assert_close("batched image", &both.image.narrow(0, k, 1).unwrap(), &one.image);
        assert_close("batched attention", &both.attention.narrow(0, k, 1).unwrap(), &one.attention);
    }
    assert!(
        p.edit(image, &prompt, noise, &[span, span], &settings, &mut |_, _| true).is_err(),
        "one span per image"
    );
}

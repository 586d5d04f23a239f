//! Every model refuses a config that cannot describe it, and weights that do not match
//! their config, with one line naming the folder and the problem: never a panic, never a
//! backtrace. Each case copies a tiny fixture folder, changes one config field and loads.

use std::path::{Path, PathBuf};

use candle_core::Device;
use serde_json::{json, Value};
use transsplat_models::clip::{Clip, ClipTextModel};
use transsplat_models::dinov2::Dinov2;
use transsplat_models::ip2p::{Ip2pEditor, Settings};
use transsplat_models::{Error, ModelDir};

fn fixtures(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else if entry.file_name() != "reference.safetensors" {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

type Load = fn(&Path) -> Result<(), Error>;

fn dinov2(dir: &Path) -> Result<(), Error> {
    Dinov2::load(&ModelDir::open(dir, "DINOv2", "hf")?, &Device::Cpu).map(|_| ())
}
fn clip(dir: &Path) -> Result<(), Error> {
    Clip::load(&ModelDir::open(dir, "CLIP", "hf")?, &Device::Cpu).map(|_| ())
}
fn clip_text(dir: &Path) -> Result<(), Error> {
    ClipTextModel::load(&ModelDir::open(dir, "CLIP text", "hf")?, &Device::Cpu).map(|_| ())
}
fn ip2p(dir: &Path) -> Result<(), Error> {
    Ip2pEditor::load(dir, Settings::default(), 0, &Device::Cpu).map(|_| ())
}

/// `(fixture, loader, config file inside it, JSON path of the field, new value, the words
/// the error must hold)`.
type Case = (&'static str, Load, &'static str, &'static [&'static str], Value, &'static [&'static str]);

fn cases() -> Vec<Case> {
    vec![
        // DINOv2
        ("dinov2", dinov2, "config.json", &["num_attention_heads"], json!(0), &["num_attention_heads is 0"]),
        (
            "dinov2",
            dinov2,
            "config.json",
            &["num_attention_heads"],
            json!(5),
            &["hidden_size 32 does not divide"],
        ),
        ("dinov2", dinov2, "config.json", &["patch_size"], json!(0), &["patch_size is 0"]),
        ("dinov2", dinov2, "config.json", &["image_size"], json!(10), &["below patch_size"]),
        ("dinov2", dinov2, "config.json", &["layer_norm_eps"], json!(-1.0), &["layer_norm_eps is -1"]),
        ("dinov2", dinov2, "config.json", &["mlp_ratio"], json!(0), &["mlp_ratio is 0"]),
        ("dinov2", dinov2, "config.json", &["hidden_size"], json!(-3), &["invalid config"]),
        (
            "dinov2",
            dinov2,
            "config.json",
            &["hidden_size"],
            json!(1u64 << 40),
            &["hidden_size is", "between 1 and"],
        ),
        (
            "dinov2",
            dinov2,
            "config.json",
            &["num_hidden_layers"],
            json!(1u64 << 40),
            &["num_hidden_layers is"],
        ),
        ("dinov2", dinov2, "config.json", &["hidden_act"], json!("relu"), &["gelu-MLP"]),
        // Config and weights disagree: the tensor and both shapes are named.
        (
            "dinov2",
            dinov2,
            "config.json",
            &["hidden_size"],
            json!(64),
            &["tensor ", "has shape [32] in the weights", "implies [64]"],
        ),
        (
            "dinov2",
            dinov2,
            "config.json",
            &["num_hidden_layers"],
            json!(3),
            &["no tensor", "encoder.layer.2"],
        ),
        // CLIP
        (
            "clip/full",
            clip,
            "config.json",
            &["text_config", "num_attention_heads"],
            json!(0),
            &["text_config: num_attention_heads is 0"],
        ),
        (
            "clip/full",
            clip,
            "config.json",
            &["vision_config", "patch_size"],
            json!(0),
            &["vision_config: patch_size is 0"],
        ),
        (
            "clip/full",
            clip,
            "config.json",
            &["vision_config", "hidden_act"],
            json!("swish"),
            &["unsupported hidden_act"],
        ),
        ("clip/full", clip, "config.json", &["projection_dim"], json!(0), &["projection_dim is 0"]),
        (
            "clip/full",
            clip,
            "config.json",
            &["vision_config", "hidden_size"],
            json!(64),
            &["tensor ", "[32]", "[64]"],
        ),
        (
            "clip/text",
            clip_text,
            "config.json",
            &["eos_token_id"],
            json!(5000),
            &["eos_token_id 5000 is outside vocab_size 1000"],
        ),
        (
            "clip/text",
            clip_text,
            "config.json",
            &["intermediate_size"],
            json!(0),
            &["intermediate_size is 0"],
        ),
        (
            "clip/text",
            clip_text,
            "config.json",
            &["vocab_size"],
            json!(999),
            &["tensor ", "[1000, 32]", "[999, 32]"],
        ),
        // InstructPix2Pix: UNet, VAE, scheduler, text encoder
        ("ip2p", ip2p, "unet/config.json", &["norm_num_groups"], json!(0), &["norm_num_groups is 0"]),
        (
            "ip2p",
            ip2p,
            "unet/config.json",
            &["norm_num_groups"],
            json!(3),
            &["does not divide into norm_num_groups 3"],
        ),
        (
            "ip2p",
            ip2p,
            "unet/config.json",
            &["attention_head_dim"],
            json!(0),
            &["attention heads of block 0 is 0"],
        ),
        (
            "ip2p",
            ip2p,
            "unet/config.json",
            &["block_out_channels"],
            json!([16, 0]),
            &["block_out_channels[1] is 0"],
        ),
        (
            "ip2p",
            ip2p,
            "unet/config.json",
            &["downsample_padding"],
            json!(1u64 << 30),
            &["downsample_padding"],
        ),
        ("ip2p", ip2p, "unet/config.json", &["norm_eps"], json!(0), &["norm_eps is 0"]),
        ("ip2p", ip2p, "unet/config.json", &["block_out_channels"], json!([16, 48]), &["tensor ", "48"]),
        ("ip2p", ip2p, "vae/config.json", &["norm_num_groups"], json!(0), &["norm_num_groups is 0"]),
        (
            "ip2p",
            ip2p,
            "vae/config.json",
            &["block_out_channels"],
            json!([]),
            &["block_out_channels must list"],
        ),
        (
            "ip2p",
            ip2p,
            "vae/config.json",
            &["block_out_channels"],
            json!(vec![8; 70]),
            &["block_out_channels must list"],
        ),
        (
            "ip2p",
            ip2p,
            "vae/config.json",
            &["layers_per_block"],
            json!(100000),
            &["layers_per_block is 100000"],
        ),
        ("ip2p", ip2p, "vae/config.json", &["scaling_factor"], json!(0), &["scaling_factor is 0"]),
        (
            "ip2p",
            ip2p,
            "scheduler/scheduler_config.json",
            &["num_train_timesteps"],
            json!(1u64 << 40),
            &["num_train_timesteps is"],
        ),
        ("ip2p", ip2p, "scheduler/scheduler_config.json", &["beta_end"], json!(2.0), &["beta_end is 2"]),
        (
            "ip2p",
            ip2p,
            "scheduler/scheduler_config.json",
            &["steps_offset"],
            json!(5000),
            &["steps_offset 5000"],
        ),
        (
            "ip2p",
            ip2p,
            "text_encoder/config.json",
            &["num_attention_heads"],
            json!(0),
            &["num_attention_heads is 0"],
        ),
    ]
}

#[test]
fn bad_configs_and_mismatched_weights_are_one_line_errors_naming_the_folder() {
    for (fixture, load, file, field, value, words) in cases() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("model");
        copy_dir(&fixtures(fixture), &dir);
        load(&dir).unwrap_or_else(|e| panic!("{fixture}: the unchanged fixture must load: {e}"));
        let path = dir.join(file);
        let mut config: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let mut slot = &mut config;
        for key in field {
            slot = slot.get_mut(*key).unwrap_or_else(|| panic!("{fixture} {file}: no {key}"));
        }
        *slot = value.clone();
        std::fs::write(&path, config.to_string()).unwrap();
        let what = format!("{fixture} {file} {field:?} = {value}");
        let err = load(&dir).err().unwrap_or_else(|| panic!("{what}: loaded")).to_string();
        assert!(!err.contains('\n'), "{what}: not one line: {err}");
        assert!(err.contains(&dir.display().to_string()), "{what}: folder not named: {err}");
        for w in words {
            assert!(err.contains(w), "{what}: expected {w:?} in {err:?}");
        }
    }
}

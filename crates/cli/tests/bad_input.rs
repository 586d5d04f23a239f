//! The bad-input contract, table-driven, through the binary: for every case the
//! command exits with status 2, prints exactly one line on stderr (`error: ...`, no
//! panic, no backtrace) that names the file and the problem, leaves every input file
//! byte-identical, and leaves no output behind (the case folder's tree of files and
//! folders is exactly what it was before the run).
//!
//! Adding a case: one more `Case::new(...)` row in [`cases`]. Arguments are split on
//! whitespace unless given with `.arg(...)`; `{d}` stands for the case's folder. Files
//! come from the input builders below (`.file(name, bytes)`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use transsplat_raster::synthetic as bench;
use transsplat_scene::{cameras, gltf, npy, ply, sog, spz, Camera, Gaussians};

// ---------------------------------------------------------------------------------
// The table

/// One bad-input case.
struct Case {
    name: &'static str,
    args: Vec<String>,
    files: Vec<(String, Vec<u8>)>,
    dirs: Vec<String>,
    /// Substrings the error line must contain (the file and the problem).
    expect: Vec<&'static str>,
    /// Runs after the files are written (e.g. chmod); returns false to skip the case.
    setup: Option<fn(&Path) -> bool>,
}

impl Case {
    fn new(name: &'static str, args: &str) -> Self {
        Case {
            name,
            args: args.split_whitespace().map(String::from).collect(),
            files: Vec::new(),
            dirs: Vec::new(),
            expect: Vec::new(),
            setup: None,
        }
    }
    /// One argument that may contain spaces.
    fn arg(mut self, a: &str) -> Self {
        self.args.push(a.to_string());
        self
    }
    fn file(mut self, name: &str, bytes: impl Into<Vec<u8>>) -> Self {
        self.files.push((name.to_string(), bytes.into()));
        self
    }
    fn dir(mut self, name: &str) -> Self {
        self.dirs.push(name.to_string());
        self
    }
    fn expect(mut self, parts: &[&'static str]) -> Self {
        self.expect.extend_from_slice(parts);
        self
    }
    fn setup(mut self, f: fn(&Path) -> bool) -> Self {
        self.setup = Some(f);
        self
    }
    /// A valid two-view cameras.json dataset in `ds/`.
    fn with_dataset(self) -> Self {
        self.file("ds/cameras.json", cameras_json(&cams(2)))
            .file("ds/images/view_0.png", png(40, 30))
            .file("ds/images/view_1.png", png(40, 30))
    }
    /// `train` on the valid dataset with one bad flag value: `message` is the error.
    fn train_flag(name: &'static str, flags: &str, message: &'static str) -> Self {
        Case::new(name, "train --data {d}/ds --out {d}/out --iters 1")
            .args(flags)
            .with_dataset()
            .expect(&[message])
    }

    /// A valid scene and cameras.json in `in/`.
    fn with_scene(self) -> Self {
        self.file("in/scene.ply", scene_ply()).file("in/cameras.json", cameras_json(&cams(3)))
    }
}

const UOT: &str = "uot --eps 0.1 --tau-s 1 --tau-t 1";
const RENDER: &str = "render --scene {d}/in/scene.ply --out {d}/out --cameras";
const EDIT: &str = "edit --scene {d}/in/scene.ply --cameras {d}/in/cameras.json --editor folder \
                    --edits {d}/edits --out {d}/out --prompt";

fn cases() -> Vec<Case> {
    vec![
        // ---- PLY scenes (info, render, views export)
        Case::new("info: truncated binary PLY", "info {d}/scene.ply")
            .file("scene.ply", truncated(scene_ply(), 100))
            .expect(&["scene.ply", "truncated"]),
        Case::new("info: wrong magic", "info {d}/scene.ply")
            .file("scene.ply", b"PLY\nformat ascii 1.0\nend_header\n".to_vec())
            .expect(&["scene.ply", "not a PLY file"]),
        Case::new("info: vertex count that lies (huge count, small file)", "info {d}/scene.ply")
            .file("scene.ply", lying_count())
            .expect(&["scene.ply", "vertex count 1000000000000", "only"]),
        Case::new("info: missing required property", "info {d}/scene.ply")
            .file("scene.ply", ascii_ply(&props_without("opacity"), 2))
            .expect(&["scene.ply", "missing required vertex property 'opacity'"]),
        Case::new("info: NaN parameter names the Gaussian", "info {d}/scene.ply")
            .file("scene.ply", nan_scene(&[7]))
            .expect(&["scene.ply", "Gaussian 7", "--drop-invalid"]),
        Case::new("info --drop-invalid: every Gaussian invalid", "info --drop-invalid {d}/scene.ply")
            .file("scene.ply", nan_scene(&[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]))
            .expect(&["scene.ply", "no Gaussians"]),
        Case::new("info: unknown PLY format", "info {d}/scene.ply")
            .file("scene.ply", b"ply\nformat binary_middle_endian 1.0\nend_header\n".to_vec())
            .expect(&["scene.ply", "unknown PLY format \"binary_middle_endian\""]),
        Case::new("info: empty file", "info {d}/scene.ply")
            .file("scene.ply", Vec::new())
            .expect(&["scene.ply", "not a PLY file"]),
        Case::new("info: folder without a scene", "info {d}/empty").dir("empty").expect(&["empty"]),
        Case::new("info: missing file", "info {d}/nope.ply").expect(&["nope.ply", "No such file"]),
        Case::new("render: truncated PLY", "render --scene {d}/in/scene.ply --out {d}/out")
            .file("in/scene.ply", truncated(scene_ply(), 3))
            .file("in/cameras.json", cameras_json(&cams(3)))
            .expect(&["scene.ply", "truncated"]),
        // ---- cameras (render, views export, edit)
        Case::new("render: malformed cameras.json", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file("in/cameras.json", b"[{\"id\": 0, \"img_name\": ".to_vec())
            .expect(&["cameras.json", "not valid JSON"]),
        Case::new("render: zero image size in cameras.json", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file("in/cameras.json", cameras_json_with(|c| c["width"] = 0.into()))
            .expect(&["cameras.json", "image size 0x30"]),
        Case::new("render: negative focal length", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file("in/cameras.json", cameras_json_with(|c| c["fx"] = (-50.0).into()))
            .expect(&["cameras.json", "focal length fx = -50"]),
        Case::new("render: negative image size", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file("in/cameras.json", cameras_json_with(|c| c["height"] = (-30).into()))
            .expect(&["cameras.json", "\"height\" is not a non-negative integer"]),
        Case::new("render: non-pinhole COLMAP camera", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.txt", "1 OPENCV 40 30 50 50 20 15 0.1 0 0 0\n")
            .file("sparse/images.txt", "1 1 0 0 0 0 0 3 1 a.png\n\n")
            .expect(&["cameras.txt", "non-zero distortion"]),
        Case::new("render: fisheye COLMAP camera", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.bin", cameras_bin(5, &[50.0, 50.0, 20.0, 15.0, 0.0, 0.0, 0.0, 0.0], 1))
            .file("sparse/images.bin", images_bin(&[(1, 1, "a.png")], 1))
            .expect(&["cameras.bin", "fisheye"]),
        Case::new("render: COLMAP camera count that lies", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.bin", cameras_bin(1, &[50.0, 50.0, 20.0, 15.0], 3))
            .file("sparse/images.bin", images_bin(&[(1, 1, "a.png")], 1))
            .expect(&["cameras.bin", "truncated: camera 1 of 3"]),
        Case::new("render: truncated COLMAP images.bin", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.bin", cameras_bin(1, &[50.0, 50.0, 20.0, 15.0], 1))
            .file("sparse/images.bin", truncated(images_bin(&[(1, 1, "a.png"), (2, 1, "b.png")], 2), 30))
            .expect(&["images.bin", "truncated: image 1 of 2"]),
        Case::new("render: COLMAP image of a camera that is not there", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.txt", "1 PINHOLE 40 30 50 50 20 15\n")
            .file("sparse/images.txt", "1 1 0 0 0 0 0 3 1 a.png\n\n2 1 0 0 0 0 0 3 2 b.png\n\n")
            .expect(&["images.txt", "camera id 2, which is not in cameras.txt"]),
        Case::new("render: transforms.json without transform_matrix", RENDER)
            .arg("{d}/in/transforms.json")
            .file("in/scene.ply", scene_ply())
            .file(
                "in/transforms.json",
                r#"{"fl_x": 50, "w": 40, "h": 30, "frames": [{"file_path": "a.png"}]}"#,
            )
            .expect(&["transforms.json", "frame 0 (\"a.png\")", "transform_matrix"]),
        Case::new("render: transforms.json whose image is missing", RENDER)
            .arg("{d}/in/transforms.json")
            .file("in/scene.ply", scene_ply())
            .file("in/transforms.json", transforms_without_size())
            .expect(&["transforms.json", "a.png was not found"]),
        Case::new("render: transforms.json whose image is corrupt", RENDER)
            .arg("{d}/in/transforms.json")
            .file("in/scene.ply", scene_ply())
            .file("in/transforms.json", transforms_without_size())
            .file("in/a.png", b"\x89PNG\r\n\x1a\n\0\0\0\rXXXX".to_vec())
            .expect(&["a.png", "cannot read the image size"]),
        Case::new(
            "views export: two cameras with the same image name",
            "views export --scene {d}/in/scene.ply --out {d}/out --cameras {d}/in/cameras.json",
        )
        .file("in/scene.ply", scene_ply())
        .file("in/cameras.json", cameras_json(&[cams(1)[0].clone(), cams(1)[0].clone()]))
        .expect(&["cameras.json", "two cameras share the image name"]),
        Case::new(
            "views export: only held-out test views",
            "views export --scene {d}/in/scene.ply --out {d}/out --cameras {d}/in/cameras.json",
        )
        .file("in/scene.ply", scene_ply())
        .file("in/cameras.json", cameras_json(&cams(1)))
        .expect(&["cameras.json", "nothing to export"]),
        // ---- output locations
        Case::new(
            "render: output folder is the input's folder",
            "render --scene {d}/in/scene.ply --out {d}/in",
        )
        .with_scene()
        .expect(&["the output contains the input", "scene.ply"]),
        Case::new(
            "render: output path is an existing file",
            "render --scene {d}/in/scene.ply --out {d}/in/cameras.json",
        )
        .with_scene()
        .expect(&["cameras.json", "the output is the input"]),
        Case::new("render: read-only output location", "render --scene {d}/in/scene.ply --out {d}/ro/out")
            .with_scene()
            .dir("ro")
            .setup(make_read_only)
            .expect(&["ro/out", "cannot create output folder"]),
        // The error names the output the user gave, not the hidden staging folder
        // beside it (`ro/.out.partial-PID`); skipped where the user can write anyway (root).
        Case::new(
            "edit: read-only output location",
            "edit --scene {d}/in/scene.ply --editor folder --edits {d}/edits --out {d}/ro/out --prompt",
        )
        .arg("make it blue")
        .with_scene()
        .dir("edits")
        .dir("ro")
        .setup(make_read_only)
        .expect(&["ro/out"]),
        Case::new(
            "edit: output folder contains the input",
            "edit --scene {d}/in/scene.ply --editor folder --edits {d}/edits --out {d}/in --prompt",
        )
        .arg("make it blue")
        .with_scene()
        .dir("edits")
        .expect(&["the output contains the input", "scene.ply"]),
        // ---- edit settings
        Case::new("edit: empty prompt", EDIT).arg("  ").with_scene().expect(&["--prompt is empty"]),
        Case::new("edit: --views 0", EDIT)
            .arg("make it blue")
            .args("--views 0")
            .with_scene()
            .dir("edits")
            .expect(&["--views"]),
        Case::new("edit: --views not a number", EDIT)
            .arg("make it blue")
            .args("--views half")
            .with_scene()
            .dir("edits")
            .expect(&["--views", "half"]),
        Case::new("edit: --views beyond the edit views", EDIT)
            .arg("make it blue")
            .args("--views 3")
            .with_scene()
            .dir("edits")
            .expect(&["--views 3 is more than the 2 edit views"]),
        Case::new("edit: unknown config key", EDIT)
            .arg("make it blue")
            .args("--config {d}/config.toml")
            .with_scene()
            .file("config.toml", "[transport]\nepsilon = 0.1\n")
            .expect(&["config.toml", "line 2, column 1: unknown field `epsilon`"]),
        Case::new("edit: config that is not TOML", EDIT)
            .arg("make it blue")
            .args("--config {d}/config.toml")
            .with_scene()
            .file("config.toml", "[transport\neps = \n")
            .expect(&["config.toml", "line 1, column 11: invalid table header"]),
        Case::new("edit: NaN in the config", EDIT)
            .arg("make it blue")
            .args("--config {d}/config.toml")
            .with_scene()
            .file("config.toml", "[loss]\nleak = nan\n")
            .expect(&["config.toml", "loss.leak must be finite"]),
        Case::new("edit: eps <= 0 through --set", EDIT)
            .arg("make it blue")
            .args("--set transport.eps=0")
            .with_scene()
            .expect(&["transport.eps", "out of range"]),
        Case::new("edit: unknown --set key", EDIT)
            .arg("make it blue")
            .args("--set transport.nope=1")
            .with_scene()
            .expect(&["unknown setting \"transport.nope\""]),
        Case::new("edit: unknown method", EDIT)
            .arg("make it blue")
            .args("--method magic")
            .with_scene()
            .expect(&["unknown method \"magic\""]),
        Case::new("edit: NaN scene", EDIT)
            .arg("make it blue")
            .file("in/scene.ply", nan_scene(&[3]))
            .file("in/cameras.json", cameras_json(&cams(3)))
            .expect(&["scene.ply", "Gaussian 3"]),
        Case::new(
            "edit: simulated editor on a scene that is not built in",
            "edit --scene {d}/in/scene.ply --editor simulated --out {d}/out --prompt",
        )
        .arg("make it blue")
        .with_scene()
        .expect(&["labels.json", "built-in scene"]),
        Case::new(
            "edit: ip2p weights folder missing",
            "edit --scene {d}/in/scene.ply --cameras {d}/in/cameras.json --editor ip2p \
             --ip2p-weights {d}/no-ip2p --out {d}/out --prompt",
        )
        .arg("make it blue")
        .with_scene()
        .expect(&["no-ip2p", "hf download timbrooks/instruct-pix2pix"]),
        Case::new(
            "edit: ip2p folder without its components",
            "edit --scene {d}/in/scene.ply --cameras {d}/in/cameras.json --editor ip2p \
             --ip2p-weights {d}/ip2p --out {d}/out --prompt",
        )
        .arg("make it blue")
        .with_scene()
        .dir("ip2p/unet")
        .expect(&["ip2p/text_encoder", "not found", "hf download timbrooks/instruct-pix2pix"]),
        Case::new("edit: DINOv2 weights folder missing", EDIT)
            .arg("make it blue")
            .args("--dino-weights {d}/no-dino")
            .with_scene()
            .dir("edits")
            .expect(&["no-dino", "hf download facebook/dinov2"]),
        Case::new("edit: DINOv2 config with zero attention heads", EDIT)
            .arg("make it blue")
            .args("--dino-weights {d}/dino")
            .with_scene()
            .dir("edits")
            .file("dino/config.json", dino_config_with("num_attention_heads", 0))
            .file("dino/model.safetensors", dino_fixture("model.safetensors"))
            .expect(&["dino/config.json", "num_attention_heads is 0"]),
        Case::new("edit: DINOv2 config that does not match its weights", EDIT)
            .arg("make it blue")
            .args("--dino-weights {d}/dino")
            .with_scene()
            .dir("edits")
            .file("dino/config.json", dino_config_with("hidden_size", 64))
            .file("dino/model.safetensors", dino_fixture("model.safetensors"))
            .expect(&["dino", "has shape [32] in the weights", "implies [64]"]),
        Case::new(
            "eval: CLIP weights folder missing",
            "eval --clip {d}/no-clip --source {d}/src --edited {d}/edit --source-prompt a \
             --target-prompt b --out {d}/out.json",
        )
        .dir("src")
        .dir("edit")
        .expect(&["no-clip", "hf download openai/clip-vit-large-patch14"]),
        Case::new(
            "eval: CLIP weights file that is not safetensors",
            "eval --clip {d}/clip --source {d}/src --edited {d}/edit --source-prompt a \
             --target-prompt b --out {d}/out.json",
        )
        .dir("src")
        .dir("edit")
        .file("src/v.png", png(4, 4))
        .file("edit/v.png", png(4, 4))
        .file("clip/config.json", "{}")
        .file("clip/model.safetensors", "garbage")
        .expect(&["clip/", "config.json"]),
        Case::new("edit: folder editor without its folder", EDIT)
            .arg("make it blue")
            .with_scene()
            .expect(&["edits", "the folder does not exist"]),
        Case::new("edit: folder editor with no edited images", EDIT)
            .arg("make it blue")
            .with_scene()
            .dir("edits")
            .expect(&["edits", "no edited image for any of the 2 views"]),
        Case::new("edit: corrupt edited image", EDIT)
            .arg("make it blue")
            .with_scene()
            .file("edits/view_1.png", b"\x89PNG\r\n\x1a\nbroken".to_vec())
            .file("edits/view_2.png", png(40, 30))
            .expect(&["view_1.png", "bad PNG"]),
        Case::new(
            "edit: command editor that fails",
            "edit --scene {d}/in/scene.ply --editor command --out {d}/out --prompt",
        )
        .arg("make it blue")
        .arg("--command")
        .arg("false")
        .with_scene()
        .expect(&["editor command `false` failed"]),
        // ---- train
        Case::new("train: an image that is a folder", "train --data {d}/ds --out {d}/out --iters 1")
            .file("ds/cameras.json", cameras_json(&cams(2)))
            .file("ds/images/view_0.png", png(40, 30))
            .dir("ds/images/view_1.png")
            .expect(&["view_1", "missing"]),
        Case::new("train: not a dataset", "train --data {d}/empty --out {d}/out")
            .dir("empty")
            .expect(&["empty", "no dataset found"]),
        Case::new("train: corrupt image", "train --data {d}/ds --out {d}/out --iters 1")
            .file("ds/cameras.json", cameras_json(&cams(2)))
            .file("ds/images/view_0.png", png(40, 30))
            .file("ds/images/view_1.png", b"\x89PNG\r\n\x1a\ngarbage".to_vec())
            .expect(&["view_1.png", "bad PNG"]),
        Case::new("train: more cameras than images", "train --data {d}/ds --out {d}/out --iters 1")
            .file("ds/cameras.json", cameras_json(&cams(3)))
            .file("ds/images/view_0.png", png(40, 30))
            .file("ds/images/view_1.png", png(40, 30))
            .expect(&["view_2", "image for camera \"view_2\" is missing"]),
        Case::new("train: image size unlike its camera", "train --data {d}/ds --out {d}/out --iters 1")
            .file("ds/cameras.json", cameras_json(&cams(2)))
            .file("ds/images/view_0.png", png(40, 30))
            .file("ds/images/view_1.png", png(30, 30))
            .expect(&["view_1.png", "30x30"]),
        Case::new("train: read-only output location", "train --data {d}/ds --out {d}/ro/out --iters 1")
            .with_dataset()
            .dir("ro")
            .setup(make_read_only)
            .expect(&["ro/out"]),
        Case::new("train: output folder is the dataset", "train --data {d}/ds --out {d}/ds --iters 1")
            .with_dataset()
            .expect(&["the output is the input", "ds"]),
        Case::new("train: zero focal length in COLMAP", "train --data {d}/ds --out {d}/out --iters 1")
            .file("ds/sparse/0/cameras.txt", "1 PINHOLE 40 30 0 50 20 15\n")
            .file("ds/sparse/0/images.txt", "1 1 0 0 0 0 0 3 1 view_0.png\n\n")
            .file("ds/images/view_0.png", png(40, 30))
            .expect(&["images.txt", "focal length fx = 0"]),
        // Flag ranges checked by the parser: one line too, naming the flag.
        Case::train_flag("train: --resolution 0", "--resolution 0", "--resolution"),
        Case::train_flag("train: --sh-degree 4", "--sh-degree 4", "--sh-degree"),
        Case::train_flag("train: --seed not a number", "--seed many", "--seed"),
        Case::train_flag(
            "train: --random-points beyond the bound",
            "--random-points 1000000000000",
            "--random-points must be at most 10000000",
        ),
        Case::train_flag(
            "train: --min-opacity of 1",
            "--min-opacity 1",
            "--min-opacity must be in [0, 1), got 1",
        ),
        Case::train_flag(
            "train: zero --densify-grad-threshold",
            "--densify-grad-threshold 0",
            "--densify-grad-threshold must be positive, got 0",
        ),
        Case::train_flag(
            "train: negative --max-screen-radius",
            "--max-screen-radius=-1",
            "--max-screen-radius must be at least 0, got -1",
        ),
        Case::train_flag(
            "train: --downscales without steps per level",
            "--downscales 2 --downscale-every 0",
            "--downscale-every must be at least 1 with --downscales 2",
        ),
        Case::train_flag(
            "train: negative --filter-3d",
            "--filter-3d=-1",
            "--filter-3d must be in [0, 10], got -1",
        ),
        Case::train_flag(
            "train: --filter-3d beyond the bound",
            "--filter-3d 20",
            "--filter-3d must be in [0, 10], got 20",
        ),
        Case::train_flag(
            "train: --downscales beyond the bound",
            "--downscales 7",
            "--downscales must be at most 6, got 7",
        ),
        Case::new(
            "train: --masks folder without a view's mask",
            "train --data {d}/ds --out {d}/out --iters 1",
        )
        .args("--masks {d}/m")
        .file("ds/cameras.json", cameras_json(&cams(2)))
        .file("ds/images/view_0.png", png(40, 30))
        .file("ds/images/view_1.png", png(40, 30))
        .file("m/view_0.png", png(40, 30))
        .expect(&["{d}/m", "no mask for camera \"view_1\""]),
        Case::new(
            "train: a declared mask_path that is not a name",
            "train --data {d}/ds --out {d}/out --iters 1",
        )
        .file(
            "ds/transforms.json",
            r#"{"fl_x": 40, "w": 40, "h": 30, "frames": [{"file_path": "a.png", "mask_path": 7,
                    "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}"#,
        )
        .file("ds/a.png", png(40, 30))
        .expect(&["transforms.json", "\"mask_path\" is not a file name"]),
        Case::new("train: a declared mask that is missing", "train --data {d}/ds --out {d}/out --iters 1")
            .file(
                "ds/transforms.json",
                r#"{"fl_x": 40, "w": 40, "h": 30, "frames": [{"file_path": "a.png", "mask_path": "m/a.png",
                    "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}"#,
            )
            .file("ds/a.png", png(40, 30))
            .expect(&["m/a.png"]),
        // ---- uot
        Case::new("uot: cost is not a .npy", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy")
            .file("cost.npy", b"garbage".to_vec())
            .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]))
            .expect(&["cost.npy", "bad magic"]),
        Case::new("uot: truncated .npy", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy")
            .file("cost.npy", truncated(npy_bytes(&[2, 3], &[1.0; 6]), 5))
            .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]))
            .expect(&["cost.npy", "data truncated"]),
        Case::new("uot: non-ASCII dtype (found by fuzzing)", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy")
            .file("cost.npy", npy_with_descr("\u{64a}u2", &[2, 3], &[0; 12]))
            .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]))
            .expect(&["cost.npy", "unsupported dtype"]),
        Case::new("uot: NaN cost", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy --out {d}/plan.npy")
            .file("cost.npy", npy_bytes(&[2, 3], &[1.0, 2.0, f32::NAN, 4.0, 5.0, 6.0]))
            .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]))
            .expect(&["cost.npy", "cost at source 0, target 2 is NaN"]),
        Case::new("uot: negative mass", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy --out {d}/plan.npy")
            .file("cost.npy", npy_bytes(&[2, 3], &[1.0; 6]))
            .file("a.npy", npy_bytes(&[2], &[0.5, -0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]))
            .expect(&["a.npy", "source mass 1 is -0.5"]),
        Case::new("uot: NaN target mass", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy")
            .file("cost.npy", npy_bytes(&[2, 3], &[1.0; 6]))
            .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, f32::NAN, 0.4]))
            .expect(&["b.npy", "target mass 1 is NaN"]),
        Case::new("uot: mass count unlike the cost", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy")
            .file("cost.npy", npy_bytes(&[2, 3], &[1.0; 6]))
            .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .expect(&["b.npy", "2 target masses", "cost.npy is 2 x 3"]),
        Case::new("uot: masses not a vector", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy")
            .file("cost.npy", npy_bytes(&[2, 3], &[1.0; 6]))
            .file("a.npy", npy_bytes(&[2, 1], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]))
            .expect(&["a.npy", "shape [2, 1]"]),
        Case::new("uot: eps <= 0", "uot --eps=-1 --tau-s 1 --tau-t 1")
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy --out {d}/plan.npy")
            .file("cost.npy", npy_bytes(&[2, 3], &[1.0; 6]))
            .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]))
            .expect(&["eps must be finite and > 0, got -1"]),
        Case::new("uot: plan into a missing folder", UOT)
            .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy --out {d}/nowhere/plan.npy")
            .file("cost.npy", npy_bytes(&[2, 3], &[1.0; 6]))
            .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
            .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]))
            .expect(&["nowhere/plan.npy", "No such file or directory (os error 2)"]),
        // ---- demo and scene
        Case::new("demo: unknown method", "demo --quick --out {d}/demo --methods naive,magic")
            .expect(&["unknown method \"magic\""]),
        Case::new("demo: bad config file", "demo --quick --out {d}/demo --config {d}/c.toml")
            .file("c.toml", "seed = -1\n")
            .expect(&["c.toml", "line 1, column 8", "expected u64"]),
        Case::new("demo: unknown scene", "demo --quick --out {d}/demo --scene nowhere")
            .expect(&["unknown scene \"nowhere\""]),
        Case::new("scene: zero width", "scene tabletop --quick --width 0 --out {d}/ds")
            .expect(&["image size 0x96"]),
        // ---- camera checks shared by every format (Camera::validate and the readers)
        Case::new("render: zero rotation in cameras.json", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file(
                "in/cameras.json",
                cameras_json_with(|c| c["rotation"] = serde_json::json!([[0, 0, 0], [0, 0, 0], [0, 0, 0]])),
            )
            .expect(&["cameras.json", "camera \"view_0\": rotation is not orthonormal"]),
        Case::new("render: non-orthonormal rotation in cameras.json", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file(
                "in/cameras.json",
                cameras_json_with(|c| c["rotation"] = serde_json::json!([[1, 0.5, 0], [0, 1, 0], [0, 0, 3]])),
            )
            .expect(&["cameras.json", "camera \"view_0\": rotation is not orthonormal"]),
        Case::new("render: reflection instead of a rotation in cameras.json", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file(
                "in/cameras.json",
                cameras_json_with(|c| c["rotation"] = serde_json::json!([[1, 0, 0], [0, 1, 0], [0, 0, -1]])),
            )
            .expect(&["cameras.json", "rotation is a reflection"]),
        Case::new("render: zero quaternion in COLMAP", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.txt", "1 PINHOLE 40 30 50 50 20 15\n")
            .file("sparse/images.txt", "1 0 0 0 0 0 0 3 1 a.png\n\n")
            .expect(&["images.txt", "line 1: image \"a.png\" has an invalid quaternion"]),
        // COLMAP stores a quaternion, normalised on reading (as COLMAP does), so the
        // only way it is not a rotation is zero (above) or not finite.
        Case::new("render: NaN quaternion in COLMAP (not a rotation)", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.txt", "1 PINHOLE 40 30 50 50 20 15\n")
            .file("sparse/images.txt", "1 1 0 0 0 0 0 3 1 a.png\n\n2 1 nan 0 0 0 0 3 1 b.png\n\n")
            .expect(&["images.txt", "line 3: image \"b.png\" has an invalid quaternion"]),
        Case::new("render: empty image name in cameras.json", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file("in/cameras.json", cameras_json_with(|c| c["img_name"] = "".into()))
            .expect(&["cameras.json", "camera 0: a camera has an empty image name"]),
        Case::new("render: empty file_path in transforms.json", RENDER)
            .arg("{d}/in/transforms.json")
            .file("in/scene.ply", scene_ply())
            .file("in/transforms.json", transforms_with(r#""fl_x": 50, "w": 40, "h": 30"#, &["a.png", ""]))
            .expect(&["transforms.json", "camera 1: a camera has an empty image name"]),
        Case::new("render: duplicate image names in cameras.json", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file("in/cameras.json", cameras_json_with(|c| c["img_name"] = "view_1".into()))
            .expect(&["cameras.json", "two cameras share the image name \"view_1\""]),
        Case::new("render: COLMAP images whose names differ only in extension", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.txt", "1 PINHOLE 40 30 50 50 20 15\n")
            .file("sparse/images.txt", "1 1 0 0 0 0 0 3 1 a.png\n\n2 1 0 0 0 0 0 3 1 a.jpg\n\n")
            .expect(&["images.txt", "two cameras share the image name \"a\" (\"a.png\" and \"a.jpg\")"]),
        Case::new("render: field of view of 7 rad in transforms.json", RENDER)
            .arg("{d}/in/transforms.json")
            .file("in/scene.ply", scene_ply())
            .file(
                "in/transforms.json",
                transforms_with(r#""camera_angle_x": 7, "w": 40, "h": 30"#, &["a.png"]),
            )
            .expect(&[
                "transforms.json",
                "frame 0 (\"a.png\"): \"camera_angle_x\" = 7 is not a field of view in radians",
            ]),
        Case::new("render: 100000x100000 camera in cameras.json", RENDER)
            .arg("{d}/in/cameras.json")
            .file("in/scene.ply", scene_ply())
            .file(
                "in/cameras.json",
                cameras_json_with(|c| {
                    c["width"] = 100_000.into();
                    c["height"] = 100_000.into()
                }),
            )
            .expect(&["cameras.json", "image size 100000x100000 is larger than 32768 pixels a side"]),
        Case::new("render: 100000x100000 camera in COLMAP", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.txt", "1 PINHOLE 100000 100000 50 50 20 15\n")
            .file("sparse/images.txt", "1 1 0 0 0 0 0 3 1 a.png\n\n")
            .expect(&[
                "cameras.txt",
                "camera 1: image size 100000x100000 is larger than 32768 pixels a side",
            ]),
        Case::new("render: COLMAP camera over the pixel cap", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.bin", cameras_bin_sized(1, &[50.0, 50.0, 20.0, 15.0], 32768, 4097))
            .file("sparse/images.bin", images_bin(&[(1, 1, "a.png")], 1))
            .expect(&["cameras.bin", "image size 32768x4097 is more than 134217728 pixels (128 million)"]),
        Case::new(
            "train: 100000x100000 camera in a COLMAP dataset",
            "train --data {d}/ds --out {d}/out --iters 1",
        )
        .file("ds/sparse/0/cameras.txt", "1 PINHOLE 100000 100000 50 50 20 15\n")
        .file("ds/sparse/0/images.txt", "1 1 0 0 0 0 0 3 1 view_0.png\n\n")
        .file("ds/images/view_0.png", png(40, 30))
        .expect(&["cameras.txt", "image size 100000x100000"]),
        Case::new("render: COLMAP images.txt missing a line", RENDER)
            .arg("{d}/sparse")
            .file("in/scene.ply", scene_ply())
            .file("sparse/cameras.txt", "1 PINHOLE 40 30 50 50 20 15\n")
            .file("sparse/images.txt", "1 1 0 0 0 0 0 3 1 a.png\n2 1 0 0 0 0 0 3 1 b.png\n\n")
            .expect(&[
                "images.txt",
                "line 2: expected the 2D points of image 1 (line 1)",
                "is a line missing?",
            ]),
        // ---- Formats and the viewer (convert, view)
        Case::new("convert: unknown output format", "convert {d}/in/scene.ply {d}/out.xyz")
            .with_scene()
            .expect(&["out.xyz", "cannot tell the output format"]),
        Case::new("convert: output is the input", "convert {d}/in/scene.ply {d}/in/scene.ply --format spz")
            .with_scene()
            .expect(&["scene.ply"]),
        Case::new("convert: scene with zero Gaussians", "convert {d}/in/scene.ply {d}/out.spz")
            .file("in/scene.ply", ply::to_bytes(&Gaussians::default()))
            .expect(&["scene.ply", "no Gaussians"]),
        Case::new("convert: NaN opacity", "convert {d}/in/scene.ply {d}/out.compressed.ply")
            .file("in/scene.ply", nan_scene(&[3]))
            .expect(&["scene.ply", "Gaussian 3", "opacity"]),
        Case::new("convert: truncated .spz", "convert {d}/in/scene.spz {d}/out.ply")
            .file("in/scene.spz", truncated(spz::to_bytes(&scene()), 40))
            .expect(&["scene.spz", "SPZ"]),
        Case::new("convert: .spz declaring 2^31 Gaussians", "convert {d}/in/scene.spz {d}/out.ply")
            .file("in/scene.spz", spz_lying_count())
            .expect(&["scene.spz", "more than the limit"]),
        Case::new("convert: truncated .glb", "convert {d}/in/scene.glb {d}/out.ply")
            .file("in/scene.glb", truncated(gltf::to_bytes(&scene()), 40))
            .expect(&["scene.glb", "glTF", "the header gives a length"]),
        Case::new("convert: .glb without KHR_gaussian_splatting", "convert {d}/in/scene.glb {d}/out.ply")
            .file("in/scene.glb", glb_without_extension())
            .expect(&["scene.glb", "no mesh primitive has the KHR_gaussian_splatting extension"]),
        Case::new("convert: truncated .sog", "convert {d}/in/scene.sog {d}/out.ply")
            .file("in/scene.sog", truncated(sog::to_bytes(&scene()), 100))
            .expect(&["scene.sog", "SOG", "not a valid zip bundle"]),
        Case::new("convert: compressed PLY with too few chunks", "convert {d}/in/scene.ply {d}/out.ply")
            .file("in/scene.ply", compressed_too_few_chunks())
            .expect(&["scene.ply", "chunks for"]),
        Case::new("convert: --cameras-out inside the input folder", "convert {d}/in/scene.ply {d}/out.spz")
            .args("--cameras {d}/in/cameras.json --cameras-out {d}/in/cameras.json")
            .with_scene()
            .expect(&["cameras.json"]),
        Case::new("view: scene with zero Gaussians", "view {d}/in/scene.ply --out {d}/page.html")
            .file("in/scene.ply", ply::to_bytes(&Gaussians::default()))
            .expect(&["scene.ply", "no Gaussians"]),
        Case::new("view: NaN in the compared scene", "view {d}/in/scene.ply --out {d}/page.html --compare")
            .arg("{d}/in/after.ply")
            .with_scene()
            .file("in/after.ply", nan_scene(&[5]))
            .expect(&["after.ply", "Gaussian 5"]),
        Case::new("view: output is the input", "view {d}/in/scene.ply --out {d}/in/scene.ply")
            .with_scene()
            .expect(&["scene.ply"]),
        Case::new("view: unknown --layer", "view {d}/in/scene.ply --out {d}/page.html --layer gate")
            .with_scene()
            .expect(&["--layer gate", "no scene has"]),
        Case::new("view: --max-mb 0", "view {d}/in/scene.ply --out {d}/page.html --max-mb 0")
            .with_scene()
            .expect(&["--max-mb 0"]),
    ]
}

/// A gzip SPZ whose header claims 2^31 Gaussians.
/// A GLB whose extension name is misspelt (same length, so the container stays valid):
/// a point cloud to any reader, not splats.
fn glb_without_extension() -> Vec<u8> {
    let mut b = gltf::to_bytes(&scene());
    let (from, to) = (b"KHR_gaussian_splatting\"", b"KHR_gaussian_splattinX\"");
    while let Some(at) = b.windows(from.len()).position(|w| w == from) {
        b[at..at + from.len()].copy_from_slice(to);
    }
    b
}

fn spz_lying_count() -> Vec<u8> {
    use std::io::Write;
    let mut raw = Vec::new();
    raw.extend_from_slice(&0x5053_474e_u32.to_le_bytes());
    raw.extend_from_slice(&3u32.to_le_bytes());
    raw.extend_from_slice(&(1u32 << 31).to_le_bytes());
    raw.extend_from_slice(&[0, 12, 0, 0]);
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    enc.write_all(&raw).unwrap();
    enc.finish().unwrap()
}

/// A compressed PLY of 300 Gaussians whose header claims one chunk (two are needed).
fn compressed_too_few_chunks() -> Vec<u8> {
    let g = bench::bench_scene(300, 1);
    let bytes = ply::compressed::encode(&g).0;
    let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header =
        String::from_utf8(bytes[..end].to_vec()).unwrap().replace("element chunk 2", "element chunk 1");
    let mut out = header.into_bytes();
    out.extend_from_slice(&bytes[end..]);
    out
}

impl Case {
    /// Several whitespace-separated arguments.
    fn args(mut self, a: &str) -> Self {
        self.args.extend(a.split_whitespace().map(String::from));
        self
    }
}

// ---------------------------------------------------------------------------------
// The runner

/// Every file (with its bytes) and folder under `root`, relative to it.
fn snapshot(root: &Path) -> BTreeMap<PathBuf, Option<Vec<u8>>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(root).unwrap().to_path_buf();
            if p.is_dir() {
                out.insert(rel, None);
                stack.push(p);
            } else {
                out.insert(rel, Some(std::fs::read(&p).unwrap()));
            }
        }
    }
    out
}

/// Runs one case; `Err` describes how it broke the contract.
fn run(case: &Case) -> Result<(), String> {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for dir in &case.dirs {
        std::fs::create_dir_all(d.join(dir)).unwrap();
    }
    for (name, bytes) in &case.files {
        let p = d.join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(&p, bytes).unwrap();
    }
    if let Some(setup) = case.setup {
        if !setup(d) {
            eprintln!("skipped (setup says not applicable here): {}", case.name);
            return Ok(());
        }
    }
    let before = snapshot(d);
    let dir = d.to_str().unwrap();
    let args: Vec<String> = case.args.iter().map(|a| a.replace("{d}", dir)).collect();
    let out = Command::new(env!("CARGO_BIN_EXE_transsplat"))
        .args(&args)
        .env("RUST_LOG", "off")
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    let after = snapshot(d);
    restore_permissions(d);
    let stderr = String::from_utf8_lossy(&out.stderr).replace(dir, "{d}");
    let mut problems = Vec::new();
    if out.status.code() != Some(2) {
        problems.push(format!("exit status {:?}, expected 2", out.status.code()));
    }
    let lines: Vec<&str> = stderr.lines().collect();
    if lines.len() != 1 || !lines[0].starts_with("error: ") {
        problems.push("stderr is not exactly one line starting with \"error: \"".into());
    }
    if stderr.contains("panicked") || stderr.contains("backtrace") {
        problems.push("stderr shows a panic".into());
    }
    for part in &case.expect {
        if !stderr.contains(part) {
            problems.push(format!("the error does not contain {part:?}"));
        }
    }
    for (path, content) in &before {
        match after.get(path) {
            None => problems.push(format!("{} was removed", path.display())),
            Some(c) if c != content => problems.push(format!("input {} was modified", path.display())),
            _ => {}
        }
    }
    for path in after.keys().filter(|p| !before.contains_key(*p)) {
        problems.push(format!("{} was left behind", path.display()));
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(format!("{}\n    args: {}\n    stderr: {stderr}", problems.join("; "), case.args.join(" ")))
    }
}

#[test]
fn every_bad_input_exits_2_with_one_line_naming_file_and_problem_and_changes_nothing() {
    let cases = cases();
    assert!(cases.len() >= 25, "the contract asks for at least 25 cases");
    // Two workers: the cases are independent processes in their own folders.
    let next = std::sync::atomic::AtomicUsize::new(0);
    let failures = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                let Some(case) = cases.get(i) else { break };
                if let Err(e) = run(case) {
                    failures.lock().unwrap().push(format!("{}: {e}", case.name));
                }
            });
        }
    });
    let failures = failures.into_inner().unwrap();
    assert!(
        failures.is_empty(),
        "{} of {} cases broke the contract:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}

/// The runner itself must be able to fail: a successful command, a second stderr
/// line, a missing substring and a left-behind output are all reported.
#[test]
fn the_runner_catches_contract_breaches() {
    let ok = Case::new("info on a valid scene", "info {d}/scene.ply").file("scene.ply", scene_ply());
    assert!(run(&ok).unwrap_err().contains("exit status Some(0)"));
    let wrong = Case::new("wrong substring", "info {d}/scene.ply")
        .file("scene.ply", Vec::new())
        .expect(&["no such words"]);
    assert!(run(&wrong).unwrap_err().contains("does not contain \"no such words\""));
    let help = Case::new("help for a missing subcommand (several lines, status 2)", "");
    assert!(run(&help).unwrap_err().contains("not exactly one line"));
    // A usage error is one line, naming the flag.
    let usage = Case::new("usage error", "info --no-such-flag").expect(&["--no-such-flag"]);
    assert!(run(&usage).is_ok());
    let leaves = Case::new("writes an output", UOT)
        .args("--cost {d}/cost.npy --source {d}/a.npy --target {d}/b.npy --out {d}/plan.npy")
        .file("cost.npy", npy_bytes(&[2, 3], &[1.0; 6]))
        .file("a.npy", npy_bytes(&[2], &[0.5, 0.5]))
        .file("b.npy", npy_bytes(&[3], &[0.3, 0.3, 0.4]));
    assert!(run(&leaves).unwrap_err().contains("was left behind"));
}

// ---------------------------------------------------------------------------------
// Output locations

/// Makes `{d}/ro` read-only; false (skip) when that does not stop writes (root).
fn make_read_only(d: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    let ro = d.join("ro");
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
    let probe = ro.join("probe");
    if std::fs::create_dir(&probe).is_ok() {
        std::fs::remove_dir(&probe).unwrap();
        return false;
    }
    true
}

fn restore_permissions(d: &Path) {
    use std::os::unix::fs::PermissionsExt;
    let ro = d.join("ro");
    if ro.is_dir() {
        let _ = std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755));
    }
}

// ---------------------------------------------------------------------------------
// Input builders

fn scene() -> Gaussians {
    bench::bench_scene(12, 1)
}

fn scene_ply() -> Vec<u8> {
    ply::to_bytes(&scene())
}

fn nan_scene(bad: &[usize]) -> Vec<u8> {
    let mut g = scene();
    for &i in bad {
        g.opacity_logits[i] = f32::NAN;
    }
    ply::to_bytes(&g)
}

fn truncated(mut bytes: Vec<u8>, cut: usize) -> Vec<u8> {
    bytes.truncate(bytes.len() - cut);
    bytes
}

/// The INRIA degree-0 property list, without `skip`.
fn props_without(skip: &str) -> Vec<&'static str> {
    [
        "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2", "rot_0",
        "rot_1", "rot_2", "rot_3",
    ]
    .into_iter()
    .filter(|p| *p != skip)
    .collect()
}

fn ascii_ply(props: &[&str], rows: usize) -> Vec<u8> {
    let mut s = format!("ply\nformat ascii 1.0\nelement vertex {rows}\n");
    for p in props {
        s.push_str(&format!("property float {p}\n"));
    }
    s.push_str("end_header\n");
    for _ in 0..rows {
        s.push_str(&vec!["0.5"; props.len()].join(" "));
        s.push('\n');
    }
    s.into_bytes()
}

/// A header claiming 10^12 vertices over a one-Gaussian body.
fn lying_count() -> Vec<u8> {
    let mut g = scene();
    let keep: Vec<bool> = (0..g.len()).map(|i| i == 0).collect();
    g.retain(&keep);
    let bytes = ply::to_bytes(&g);
    let text = String::from_utf8_lossy(&bytes);
    let at = text.find("element vertex 1\n").unwrap();
    let mut out = bytes[..at].to_vec();
    out.extend_from_slice(b"element vertex 1000000000000\n");
    out.extend_from_slice(&bytes[at + "element vertex 1\n".len()..]);
    out
}

fn cams(n: usize) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let mut c = bench::bench_camera(40, 30);
            c.name = format!("view_{i}");
            c.translation[0] += 0.1 * i as f32;
            c
        })
        .collect()
}

fn cameras_json(cams: &[Camera]) -> Vec<u8> {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("cameras.json");
    cameras::inria::write(&p, cams).unwrap();
    std::fs::read(p).unwrap()
}

/// A valid cameras.json with `edit` applied to its first camera.
fn cameras_json_with(edit: fn(&mut serde_json::Value)) -> Vec<u8> {
    let mut v: serde_json::Value = serde_json::from_slice(&cameras_json(&cams(3))).unwrap();
    edit(&mut v[0]);
    serde_json::to_vec(&v).unwrap()
}

fn transforms_without_size() -> Vec<u8> {
    br#"{"camera_angle_x": 0.7, "frames": [{"file_path": "a.png",
        "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}]}"#
        .to_vec()
}

/// COLMAP cameras.bin holding `count` in its header and one camera of `model`.
fn cameras_bin(model: i32, params: &[f64], count: u64) -> Vec<u8> {
    let mut b = count.to_le_bytes().to_vec();
    b.extend_from_slice(&1u32.to_le_bytes());
    b.extend_from_slice(&model.to_le_bytes());
    b.extend_from_slice(&40u64.to_le_bytes());
    b.extend_from_slice(&30u64.to_le_bytes());
    for p in params {
        b.extend_from_slice(&p.to_le_bytes());
    }
    b
}

/// COLMAP images.bin with (image id, camera id, name) records and `count` in its header.
fn images_bin(images: &[(u32, u32, &str)], count: u64) -> Vec<u8> {
    let mut b = count.to_le_bytes().to_vec();
    for (id, cam, name) in images {
        b.extend_from_slice(&id.to_le_bytes());
        for v in [1.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.extend_from_slice(&cam.to_le_bytes());
        b.extend_from_slice(name.as_bytes());
        b.push(0);
        b.extend_from_slice(&0u64.to_le_bytes());
    }
    b
}

fn png(w: usize, h: usize) -> Vec<u8> {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("a.png");
    transsplat_scene::image::write_png(&p, w, h, &vec![0.5; w * h * 3]).unwrap();
    std::fs::read(p).unwrap()
}

fn npy_bytes(shape: &[usize], data: &[f32]) -> Vec<u8> {
    npy::to_bytes(shape, data)
}

fn npy_with_descr(descr: &str, shape: &[usize], payload: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({}), }}\n", dims.join(", "));
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend_from_slice(&(header.len() as u16).to_le_bytes());
    b.extend_from_slice(header.as_bytes());
    b.extend_from_slice(payload);
    b
}

// ---------------------------------------------------------------------------------
// Camera checks: inputs, and `info` on finite but huge log-scales

/// A transforms.json with the top-level fields `top` and one identity-pose frame per
/// `file_path`.
fn transforms_with(top: &str, names: &[&str]) -> Vec<u8> {
    let frames: Vec<String> = names
        .iter()
        .map(|n| {
            format!(
                r#"{{"file_path": "{n}", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]}}"#
            )
        })
        .collect();
    format!(r#"{{{top}, "frames": [{}]}}"#, frames.join(", ")).into_bytes()
}

/// COLMAP cameras.bin with one camera of `model` and the given size.
fn cameras_bin_sized(model: i32, params: &[f64], width: u64, height: u64) -> Vec<u8> {
    let mut b = 1u64.to_le_bytes().to_vec();
    b.extend_from_slice(&1u32.to_le_bytes());
    b.extend_from_slice(&model.to_le_bytes());
    b.extend_from_slice(&width.to_le_bytes());
    b.extend_from_slice(&height.to_le_bytes());
    for p in params {
        b.extend_from_slice(&p.to_le_bytes());
    }
    b
}

/// Not a bad input: a log-scale of 80 (or 100, 1000) is finite, so `info` succeeds and
/// every statistic it prints is a finite number (it printed "mean NaN" where exp of a
/// log-scale overflowed f32); like the table, it writes nothing.
#[test]
fn info_on_huge_finite_log_scales_prints_finite_statistics() {
    for ls in [80.0f32, 100.0, 1000.0] {
        let tmp = tempfile::tempdir().unwrap();
        let mut g = scene();
        g.log_scales[3] = [ls, ls, ls];
        g.log_scales[5][1] = ls;
        let p = tmp.path().join("scene.ply");
        std::fs::write(&p, ply::to_bytes(&g)).unwrap();
        let before = snapshot(tmp.path());
        for json in [false, true] {
            let mut cmd = Command::new(env!("CARGO_BIN_EXE_transsplat"));
            cmd.arg("info").env("RUST_LOG", "off");
            if json {
                cmd.arg("--json");
            }
            let out = cmd.arg(&p).output().unwrap();
            let stdout = String::from_utf8_lossy(&out.stdout);
            assert!(out.status.success(), "log-scale {ls}: {}", String::from_utf8_lossy(&out.stderr));
            if json {
                let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
                assert_eq!(v["max_log_scale"]["max"].as_f64(), Some(ls as f64), "{stdout}");
                // Over f64's range (e^709.8) a scale is null in JSON; its log is there.
                assert_eq!(v["scale"]["max"].is_null(), ls > 709.0, "{stdout}");
                let mean = v["scale"]["mean"].as_f64();
                assert!(ls > 709.0 || mean.is_some_and(|m| m.is_finite() && m > 1e30), "{stdout}");
                for (k, s) in v.as_object().unwrap().iter().filter(|(_, s)| s.is_object()) {
                    let flat: Vec<&serde_json::Value> = if k == "position" {
                        s.as_object()
                            .unwrap()
                            .values()
                            .flat_map(|a| a.as_object().unwrap().values())
                            .collect()
                    } else {
                        s.as_object().unwrap().values().collect()
                    };
                    let huge = ls > 709.0 && (k == "scale" || k == "max_scale");
                    for x in flat {
                        assert!(huge || x.as_f64().is_some_and(f64::is_finite), "{k}: {x} in {stdout}");
                    }
                }
            } else {
                let stats = stdout.lines().skip_while(|l| !l.starts_with("bounding box")).skip(1);
                for t in stats.flat_map(|l| l.split_whitespace()) {
                    let t = t.trim_matches(|c| c == '(' || c == ')');
                    assert!(!t.contains("NaN") && !t.contains("inf"), "log-scale {ls}: {t:?} in\n{stdout}");
                }
                let max_line = stdout.lines().find(|l| l.starts_with("max scale")).unwrap();
                let want = match ls {
                    80.0 => "max 5.5406e34",
                    100.0 => "max 2.6881e43",
                    _ => "max 1.9701e434",
                };
                assert!(max_line.ends_with(want), "{max_line}");
            }
        }
        assert_eq!(snapshot(tmp.path()), before, "info wrote something");
    }
}

/// A file of the tiny DINOv2 fixture of the models crate.
fn dino_fixture(name: &str) -> Vec<u8> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/dinov2");
    std::fs::read(dir.join(name)).unwrap()
}

/// The DINOv2 fixture's config.json with one field changed.
fn dino_config_with(field: &str, value: u64) -> Vec<u8> {
    let mut config: serde_json::Value = serde_json::from_slice(&dino_fixture("config.json")).unwrap();
    config[field] = value.into();
    config.to_string().into_bytes()
}

//! Helpers shared by the end-to-end tests that run the `transsplat` binary.
#![allow(dead_code)] // each test file uses a different subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The binary under test.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_transsplat"))
}

/// Stdout and stderr of a finished run, for assertion messages.
pub fn text(o: &Output) -> String {
    format!("{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Asserts that a run succeeded, showing its output otherwise.
pub fn ok(o: &Output) {
    assert!(o.status.success(), "{}", text(o));
}

/// Writes the quick built-in tabletop scene to `dir/name` and returns its path.
pub fn quick_scene_in(dir: &Path, name: &str) -> PathBuf {
    let ds = dir.join(name);
    ok(&bin().args(["scene", "tabletop", "--quick", "--out"]).arg(&ds).output().unwrap());
    ds
}

/// [`quick_scene_in`] with the folder name `ds`.
pub fn quick_scene(dir: &Path) -> PathBuf {
    quick_scene_in(dir, "ds")
}

/// "Edits" every exported view in `dir` in place, the way an outside 2D tool would:
/// the right half turned blue. Returns the file names it edited.
pub fn tint(dir: &Path) -> Vec<String> {
    let mut names = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "png") {
            let mut img = transsplat_scene::image::read(&p).unwrap();
            let w = img.width;
            for (i, px) in img.data.chunks_exact_mut(3).enumerate() {
                if i % w > w / 2 {
                    px[2] = 1.0;
                }
            }
            transsplat_scene::image::write_png(&p, img.width, img.height, &img.data).unwrap();
            names.push(p.file_name().unwrap().to_string_lossy().into_owned());
        }
    }
    names.sort();
    names
}

//! The folder editor: edited images made by any 2D tool, one per view.
//!
//! Layout of the folder `DIR`:
//!
//! - `DIR/<stem>.png` (or `.jpg` / `.jpeg`, any case): the edited image of the view
//!   whose camera image name has stem `<stem>` (`00012.png` → `00012`). RGBA is
//!   composited on black (the render background), greyscale is expanded to RGB. An
//!   image of another size is resized bilinearly to the view's size, with a warning.
//! - `DIR/masks/<stem>.png` (optional): the target mask, grey, > 0.5 inside.
//!
//! The attention A_v is the mask when there is one, else the smoothed change map
//! |Î − I| ([`change_attention`]). Views without an edited image are skipped with a
//! warning (`None`); a folder with none at all is [`Error::NoEdits`].
//!
//! [`export_views`] writes the other half: `DIR/<stem>.png` per source view and
//! `DIR/views.json` (`transsplat views export`), ready for editing elsewhere.

use crate::features::change_attention;
use crate::resize::resize_bilinear;
use crate::{EditedView, Editor, Error, SourceView};
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use transsplat_scene::{atomic, image, npy, Camera};

/// The edited image for `stem` in `dir`, if any.
fn find_image(dir: &Path, stem: &str) -> Option<PathBuf> {
    image::find_with_extension(&dir.join(stem))
}

/// Reads an image as grey `H × W` (mean of RGB), resized to `w × h`, with a warning
/// when the size differs.
fn read_grey(path: &Path, w: usize, h: usize) -> Result<Vec<f32>, Error> {
    let img = image::read(path)?.composite([0.0; 3]);
    let grey: Vec<f32> = img.data.chunks_exact(3).map(|p| (p[0] + p[1] + p[2]) / 3.0).collect();
    if (img.width, img.height) != (w, h) {
        tracing::warn!(
            "{}: mask is {}x{}, the view is {w}x{h}; resizing it",
            path.display(),
            img.width,
            img.height
        );
        return Ok(resize_bilinear(&grey, img.width, img.height, 1, w, h));
    }
    Ok(grey)
}

/// Reads an attention map `.npy` (`H × W` or `H × W × 1` float32, at the view's size or
/// the edited image's), resized to `w × h`; NaN and negative values become 0.
fn read_attention(path: &Path, w: usize, h: usize, alt: (usize, usize)) -> Result<Vec<f32>, Error> {
    let a = npy::read(path)?;
    let (ah, aw) = match a.shape[..] {
        [ah, aw] | [ah, aw, 1] => (ah, aw),
        _ => {
            return Err(transsplat_scene::Error::format(
                path,
                format!("attention must be an H×W float32 array, got shape {:?}", a.shape),
            )
            .into())
        }
    };
    if (aw, ah) != (w, h) && (aw, ah) != alt {
        return Err(transsplat_scene::Error::format(
            path,
            format!("attention is {aw}x{ah} but the view is {w}x{h}"),
        )
        .into());
    }
    let clean: Vec<f32> = a.data.iter().map(|&v| if v.is_finite() && v > 0.0 { v } else { 0.0 }).collect();
    Ok(resize_bilinear(&clean, aw, ah, 1, w, h))
}

/// Reads the edits of `views` from `dir` (see the module doc); `attention_dir`, when
/// given, may hold `<stem>.npy` attention maps that replace the change map.
pub(crate) fn read_edits(
    dir: &Path,
    views: &[SourceView],
    attention_dir: Option<&Path>,
) -> Result<Vec<Option<EditedView>>, Error> {
    for v in views {
        v.check()?;
    }
    let masks = dir.join("masks");
    let mut out = Vec::with_capacity(views.len());
    let mut missing = Vec::new();
    for v in views {
        let stem = v.camera.stem();
        let (w, h) = v.size();
        let Some(path) = find_image(dir, &stem) else {
            missing.push(stem);
            out.push(None);
            continue;
        };
        let img = image::read(&path)?.composite([0.0; 3]);
        let data = if (img.width, img.height) != (w, h) {
            tracing::warn!(
                "{}: edited image is {}x{}, the view is {w}x{h}; resizing it",
                path.display(),
                img.width,
                img.height
            );
            resize_bilinear(&img.data, img.width, img.height, 3, w, h)
        } else {
            img.data
        };
        let mask_path = masks.join(format!("{stem}.png"));
        let mask: Option<Vec<f32>> = if mask_path.is_file() {
            Some(read_grey(&mask_path, w, h)?.into_iter().map(|v| if v > 0.5 { 1.0 } else { 0.0 }).collect())
        } else {
            None
        };
        let npy_path = attention_dir.map(|d| d.join(format!("{stem}.npy"))).filter(|p| p.is_file());
        let attention = match (&npy_path, &mask) {
            (Some(p), _) => read_attention(p, w, h, (img.width, img.height))?,
            (None, Some(m)) => m.clone(),
            (None, None) => change_attention(v.image, &data, w, h),
        };
        out.push(Some(EditedView::new(data, w, h, attention, mask)));
    }
    if out.iter().all(Option::is_none) {
        let first = views.first().map(|v| v.camera.stem()).unwrap_or_default();
        let why = if dir.is_dir() { "has no edited image" } else { "does not exist" };
        return Err(Error::NoEdits(format!(
            "{}: the folder {why} for any of the {} views; expected files named like the views, e.g. {}",
            dir.display(),
            views.len(),
            dir.join(format!("{first}.png")).display()
        )));
    }
    if !missing.is_empty() {
        let shown: Vec<&str> = missing.iter().take(8).map(String::as_str).collect();
        let more = if missing.len() > shown.len() {
            format!(" and {} more", missing.len() - shown.len())
        } else {
            String::new()
        };
        tracing::warn!(
            "{}: no edited image for {} of {} views ({}{more}); using the rest",
            dir.display(),
            missing.len(),
            views.len(),
            shown.join(", ")
        );
    }
    Ok(out)
}

/// Edited images from a folder (see the module doc). The prompt is not used.
#[derive(Clone, Debug)]
pub struct FolderEditor {
    dir: PathBuf,
}

impl FolderEditor {
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        FolderEditor { dir: dir.into() }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Editor for FolderEditor {
    fn name(&self) -> &str {
        "folder"
    }

    fn edit(&mut self, views: &[SourceView], _prompt: &str) -> Result<Vec<Option<EditedView>>, Error> {
        read_edits(&self.dir, views, None)
    }
}

/// One entry of `views.json`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ViewEntry {
    /// The view's stem: the edited image goes in `<name>.png`.
    pub name: String,
    /// File name written for it (`<name>.png`).
    pub file: String,
    /// Index of the view in the camera list.
    pub index: usize,
    pub width: usize,
    pub height: usize,
}

/// The `views` list written to `views.json` / `request.json`.
pub fn view_entries(views: &[SourceView]) -> Result<Vec<ViewEntry>, Error> {
    let mut seen = HashSet::new();
    views
        .iter()
        .map(|v| {
            v.check()?;
            let name = v.camera.stem();
            if !seen.insert(name.clone()) {
                return Err(Error::Invalid(format!(
                    "two views share the image name {name:?}; their files would overwrite each other"
                )));
            }
            let (width, height) = v.size();
            Ok(ViewEntry { file: format!("{name}.png"), name, index: v.index, width, height })
        })
        .collect()
}

/// Writes `<stem>.png` for every view and `views.json` (`{"views": [{"name", "file",
/// "index", "width", "height"}]}`) into `dir` (created if needed). Every file is
/// written atomically.
pub fn export_views(views: &[SourceView], dir: &Path) -> Result<(), Error> {
    for v in views {
        v.check()?;
    }
    let cams: Vec<(usize, &Camera)> = views.iter().map(|v| (v.index, v.camera)).collect();
    export_views_with(&cams, dir, |k, _, _| Ok(views[k].image.to_vec()))?;
    Ok(())
}

/// [`export_views`] for views rendered one at a time (so a large scene's views never
/// all sit in memory): `image_of(k, index, camera)` returns view k's `H × W × 3` image.
/// Returns the entries written to `views.json`.
pub fn export_views_with(
    cameras: &[(usize, &Camera)],
    dir: &Path,
    mut image_of: impl FnMut(usize, usize, &Camera) -> Result<Vec<f32>, Error>,
) -> Result<Vec<ViewEntry>, Error> {
    let mut seen = HashSet::new();
    let mut entries = Vec::with_capacity(cameras.len());
    for &(index, cam) in cameras {
        let name = cam.stem();
        if !seen.insert(name.clone()) {
            return Err(Error::Invalid(format!(
                "two views share the image name {name:?}; their files would overwrite each other"
            )));
        }
        let (width, height) = (cam.width as usize, cam.height as usize);
        entries.push(ViewEntry { file: format!("{name}.png"), name, index, width, height });
    }
    std::fs::create_dir_all(dir).map_err(|e| transsplat_scene::Error::io(dir, e))?;
    for (k, (&(index, cam), e)) in cameras.iter().zip(&entries).enumerate() {
        let img = image_of(k, index, cam)?;
        if img.len() != e.width * e.height * 3 {
            return Err(Error::Invalid(format!(
                "view {index} ({}): image has {} values but the camera is {}x{}",
                cam.name,
                img.len(),
                e.width,
                e.height
            )));
        }
        image::write_png(&dir.join(&e.file), e.width, e.height, &img)?;
    }
    let json = serde_json::json!({ "views": entries });
    let text = serde_json::to_string_pretty(&json).expect("plain data serialises");
    atomic::write_bytes(&dir.join("views.json"), text.as_bytes())?;
    Ok(entries)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn camera(name: &str, w: u32, h: u32) -> Camera {
        Camera {
            name: name.into(),
            width: w,
            height: h,
            fx: 10.0,
            fy: 10.0,
            cx: w as f32 / 2.0,
            cy: h as f32 / 2.0,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        }
    }

    fn grey_png(path: &Path, w: usize, h: usize, f: impl Fn(usize, usize) -> f32) {
        let rgb: Vec<f32> = (0..w * h).flat_map(|i| [f(i % w, i / w); 3]).collect();
        image::write_png(path, w, h, &rgb).unwrap();
    }

    #[test]
    fn missing_resized_and_masked_views() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let cams = [camera("a.png", 8, 6), camera("sub/b.jpg", 8, 6), camera("c", 8, 6)];
        let src = vec![0.0f32; 8 * 6 * 3];
        let views: Vec<SourceView> =
            cams.iter().enumerate().map(|(i, c)| SourceView { index: i, camera: c, image: &src }).collect();
        // a: same size, a bright square at (2..4, 2..4); b: half size; c: missing
        grey_png(
            &d.join("a.png"),
            8,
            6,
            |x, y| if (2..4).contains(&x) && (2..4).contains(&y) { 1.0 } else { 0.0 },
        );
        grey_png(&d.join("b.png"), 4, 3, |_, _| 0.6);
        std::fs::create_dir(d.join("masks")).unwrap();
        grey_png(&d.join("masks/b.png"), 8, 6, |x, _| if x < 4 { 0.9 } else { 0.2 });
        let out = FolderEditor::new(d).edit(&views, "ignored").unwrap();
        assert_eq!(out.len(), 3);
        let a = out[0].as_ref().unwrap();
        assert_eq!((a.width, a.height, a.image.len()), (8, 6, 8 * 6 * 3));
        assert!(a.mask.is_none());
        // change attention: peaks inside the square, smaller far away
        assert!(a.attention[2 * 8 + 2] > 3.0 * a.attention[5 * 8 + 7], "{:?}", a.attention);
        let b = out[1].as_ref().unwrap();
        assert_eq!(b.image.len(), 8 * 6 * 3);
        assert!(b.image.iter().all(|v| (v - 0.6).abs() < 2.0 / 255.0), "resized constant image");
        let m = b.mask.as_ref().unwrap();
        assert_eq!(m[0], 1.0);
        assert_eq!(m[7], 0.0);
        assert_eq!(&b.attention, m, "attention comes from the mask");
        assert!(out[2].is_none());
    }

    #[test]
    fn no_edits_is_an_error_naming_the_expected_file() {
        let dir = tempfile::tempdir().unwrap();
        let cam = camera("00007.png", 4, 4);
        let src = vec![0.0f32; 4 * 4 * 3];
        let views = [SourceView { index: 7, camera: &cam, image: &src }];
        std::fs::write(dir.path().join("other.png"), b"x").unwrap();
        let e = FolderEditor::new(dir.path()).edit(&views, "").unwrap_err();
        assert!(matches!(e, Error::NoEdits(_)));
        let msg = e.to_string();
        assert!(msg.contains("00007.png") && msg.contains("has no edited image"), "{msg}");
        let e = FolderEditor::new(dir.path().join("nope")).edit(&views, "").unwrap_err().to_string();
        assert!(e.contains("does not exist"), "{e}");
        // an unreadable edited image is an error naming it, not a skipped view
        std::fs::write(dir.path().join("00007.jpg"), b"garbage").unwrap();
        let e = FolderEditor::new(dir.path()).edit(&views, "").unwrap_err().to_string();
        assert!(e.contains("00007.jpg"), "{e}");
    }

    #[test]
    fn export_writes_images_and_a_listing() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("views");
        let cams = [camera("x/0001.png", 3, 2), camera("0002.jpg", 3, 2)];
        let imgs = [vec![0.2f32; 18], vec![0.8f32; 18]];
        let views: Vec<SourceView> = cams
            .iter()
            .zip(&imgs)
            .enumerate()
            .map(|(i, (c, m))| SourceView { index: i, camera: c, image: m })
            .collect();
        export_views(&views, &out).unwrap();
        let back = image::read(&out.join("0002.png")).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert!((back.data[0] - 0.8).abs() < 1.0 / 255.0);
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("views.json")).unwrap()).unwrap();
        assert_eq!(json["views"][0]["name"], "0001");
        assert_eq!(json["views"][1]["file"], "0002.png");
        assert_eq!(json["views"][1]["width"], 3);
        // exported views read back unchanged give zero change attention
        let back = FolderEditor::new(&out).edit(&views, "").unwrap();
        assert!(back[0].as_ref().unwrap().attention.iter().all(|&a| a < 1e-6));
        // duplicate names are refused
        let dup = [views[0], views[0]];
        assert!(matches!(export_views(&dup, &out), Err(Error::Invalid(_))));
    }
}

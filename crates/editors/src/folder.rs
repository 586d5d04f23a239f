//! The folder editor: edited images made by any 2D tool, one per view.
//!
//! Layout of the folder `DIR` (docs/method.md#e6-sharded-views-and-content-names):
//!
//! - `DIR/<stem>.<key>.png` (or `.jpg` / `.jpeg`, any case): the edited image of the
//!   view whose camera image name has stem `<stem>` (`00012.png` → `00012`), named by
//!   content: `<key>` is [`fingerprint::view`] of the scene and the camera, as
//!   `transsplat views export` names the renders. A plain `DIR/<stem>.png` is read too
//!   (an image named by hand); the content name wins when both are there. An image
//!   named for the same view of another scene or camera is refused, never used.
//! - The images may also lie one folder down (`DIR/0/`, `DIR/1/`, …): a folder
//!   assembled from shards (`views export --shard I/N`), each shard's edits in its own
//!   folder or all copied together. One view with images in two places is refused.
//! - `masks/<name>.png` beside an image (optional): the target mask, grey, > 0.5 inside.
//!
//! RGBA is composited on black (the render background), greyscale is expanded to RGB.
//! An image of another size is resized bilinearly to the view's size, with a warning.
//! The attention A_v is the mask when there is one, else the smoothed change map
//! |Î − I| ([`change_attention`]). Views without an edited image are skipped with a
//! warning (`None`); a folder with none at all is [`Error::NoEdits`].
//!
//! [`export_views`] writes the other half: the renders under the same names and
//! `views.json` (`transsplat views export`), ready for editing elsewhere; [`Shard`]
//! splits them across jobs.

use crate::features::change_attention;
use crate::resize::resize_bilinear;
use crate::{EditedView, Editor, Error, SourceView};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use transsplat_scene::{atomic, fingerprint, image, npy, Camera};

/// Subfolders that hold masks and attention maps, never edited images.
const AUX_DIRS: [&str; 2] = ["masks", "attention"];

/// The file name stem a view's files carry: `<stem>.<key>` with the scene's
/// fingerprint, plain `<stem>` without one.
pub fn content_name(cam: &Camera, scene: Option<&str>) -> String {
    match scene {
        Some(fp) => format!("{}.{}", cam.stem(), fingerprint::view(fp, cam)),
        None => cam.stem(),
    }
}

/// The folders that may hold edited images (`dir` and its subfolders, one level) and
/// the file stems of every image in them.
struct EditFolders {
    folders: Vec<PathBuf>,
    stems: HashMap<String, PathBuf>,
}

impl EditFolders {
    fn scan(dir: &Path) -> Self {
        let mut folders = vec![dir.to_path_buf()];
        let mut stems = HashMap::new();
        let mut k = 0;
        while k < folders.len() {
            let Ok(read) = std::fs::read_dir(&folders[k]) else {
                k += 1;
                continue;
            };
            let mut subs = Vec::new();
            for entry in read.flatten() {
                let path = entry.path();
                if path.is_dir() {
                    let aux = entry.file_name().to_str().is_some_and(|n| AUX_DIRS.contains(&n));
                    if k == 0 && !aux {
                        subs.push(path);
                    }
                } else if image::has_image_extension(&path) {
                    if let Some(stem) = path.file_stem().and_then(|s| s.to_str()) {
                        stems.entry(stem.to_string()).or_insert(path.clone());
                    }
                }
            }
            subs.sort();
            folders.extend(subs);
            k += 1;
        }
        EditFolders { folders, stems }
    }

    /// The edited image of the view named `name`: in at most one folder.
    fn find(&self, name: &str) -> Result<Option<PathBuf>, Error> {
        let found: Vec<PathBuf> =
            self.folders.iter().filter_map(|f| image::find_with_extension(&f.join(name))).collect();
        match &found[..] {
            [] => Ok(None),
            [one] => Ok(Some(one.clone())),
            [a, b, ..] => Err(Error::Invalid(format!(
                "{}: a second edited image of the same view is {}; keep one (are two shards overlapping?)",
                a.display(),
                b.display()
            ))),
        }
    }

    /// The edited image of view `cam` (see the module doc): its content name, else its
    /// plain stem; an image named for the same view of another scene or camera is an
    /// error.
    fn image_of(&self, cam: &Camera, scene: Option<&str>) -> Result<Option<PathBuf>, Error> {
        if let Some(fp) = scene {
            if let Some(p) = self.find(&content_name(cam, Some(fp)))? {
                return Ok(Some(p));
            }
        }
        if let Some(p) = self.find(&cam.stem())? {
            return Ok(Some(p));
        }
        let Some(fp) = scene else { return Ok(None) };
        let prefix = format!("{}.", cam.stem());
        let stale =
            self.stems.iter().find(|(s, _)| s.strip_prefix(&prefix).is_some_and(fingerprint::is_view_key));
        match stale {
            Some((_, path)) => Err(Error::Invalid(format!(
                "{}: made for another scene or camera than view {} (its content name is {}); \
                 remove it or export the views again",
                path.display(),
                cam.name,
                content_name(cam, Some(fp))
            ))),
            None => Ok(None),
        }
    }
}

/// Reads an image as grey (mean of RGB, RGBA composited on black): its `H × W` values
/// and its `(width, height)`. The one reader of mask files (the folder and command
/// editors' `masks/`, the mask-folder segmenter).
pub(crate) fn read_grey(path: &Path) -> Result<(Vec<f32>, usize, usize), Error> {
    let img = image::read(path)?.composite([0.0; 3]);
    let grey = img.data.chunks_exact(3).map(|p| (p[0] + p[1] + p[2]) / 3.0).collect();
    Ok((grey, img.width, img.height))
}

/// A grey plane as a binary mask: 1 where the value is above 0.5, else 0.
pub(crate) fn binarize(grey: Vec<f32>) -> Vec<f32> {
    grey.into_iter().map(|v| if v > 0.5 { 1.0 } else { 0.0 }).collect()
}

/// Reads an editor's mask image as a binary `H × W` mask at the view's size `w × h`,
/// resized with a warning when its size differs.
fn read_editor_mask(path: &Path, w: usize, h: usize) -> Result<Vec<f32>, Error> {
    let (grey, gw, gh) = read_grey(path)?;
    if (gw, gh) != (w, h) {
        tracing::warn!("{}: mask is {gw}x{gh}, the view is {w}x{h}; resizing it", path.display());
        return Ok(binarize(resize_bilinear(&grey, gw, gh, 1, w, h)));
    }
    Ok(binarize(grey))
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

/// Reads the edits of `views` from `dir` (see the module doc). `scene`, the scene's
/// [`fingerprint::scene`], selects content-named images (plain names only without it);
/// `attention_dir`, when given, may hold `<stem>.npy` attention maps that replace the
/// change map.
pub(crate) fn read_edits(
    dir: &Path,
    views: &[SourceView],
    scene: Option<&str>,
    attention_dir: Option<&Path>,
) -> Result<Vec<Option<EditedView>>, Error> {
    for v in views {
        v.check()?;
    }
    let folders = EditFolders::scan(dir);
    let mut out = Vec::with_capacity(views.len());
    let mut missing = Vec::new();
    for v in views {
        let stem = v.camera.stem();
        let (w, h) = v.size();
        let Some(path) = folders.image_of(v.camera, scene)? else {
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
        let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or(&stem);
        let mask_path = path.with_file_name("masks").join(format!("{name}.png"));
        let mask: Option<Vec<f32>> =
            if mask_path.is_file() { Some(read_editor_mask(&mask_path, w, h)?) } else { None };
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
    scene: Option<String>,
}

impl FolderEditor {
    /// Reads plain names only (`<stem>.png`); see [`FolderEditor::for_scene`].
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        FolderEditor { dir: dir.into(), scene: None }
    }

    /// Reads the content-named images of the scene with this [`fingerprint::scene`]
    /// (and plain names), refusing those named for another scene.
    pub fn for_scene(mut self, scene: impl Into<String>) -> Self {
        self.scene = Some(scene.into());
        self
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
        read_edits(&self.dir, views, self.scene.as_deref(), None)
    }
}

/// One share of the edit views for a job of its own: the view at position `p` of the
/// edit-view list belongs to shard `p mod count` (round robin, so shards differ by at
/// most one view and each spans the whole orbit).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// 0-based, below `count` (a Slurm array `--array=0-(N-1)` gives it directly).
    pub index: usize,
    pub count: usize,
}

impl Shard {
    /// The most shards a view list is split into.
    pub const MAX_COUNT: usize = 1 << 20;

    /// Parses `I/N` with `0 ≤ I < N ≤` [`Shard::MAX_COUNT`].
    pub fn parse(s: &str) -> Result<Shard, String> {
        let (i, n) = s.split_once('/').ok_or_else(|| format!("expected I/N (e.g. 0/4), got {s:?}"))?;
        let num =
            |t: &str| t.trim().parse::<usize>().map_err(|e| format!("{s:?}: {t:?} is not a count: {e}"));
        let (index, count) = (num(i)?, num(n)?);
        if count == 0 || count > Self::MAX_COUNT || index >= count {
            return Err(format!(
                "{s:?}: need 0 <= I < N <= {}; shards are numbered from 0 (0/{count} .. {}/{count})",
                Self::MAX_COUNT,
                count.saturating_sub(1)
            ));
        }
        Ok(Shard { index, count })
    }

    /// Whether the view at `position` of the edit-view list is this shard's.
    pub fn holds(&self, position: usize) -> bool {
        position % self.count == self.index
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// One entry of `views.json`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ViewEntry {
    /// The view's stem.
    pub name: String,
    /// File name written for it (its [`content_name`] with `.png`); the edited image
    /// goes back under the same name.
    pub file: String,
    /// Index of the view in the camera list.
    pub index: usize,
    pub width: usize,
    pub height: usize,
}

fn entry(index: usize, cam: &Camera, scene: Option<&str>) -> ViewEntry {
    let (width, height) = (cam.width as usize, cam.height as usize);
    ViewEntry { file: format!("{}.png", content_name(cam, scene)), name: cam.stem(), index, width, height }
}

/// Refuses two views with one image name: their files would overwrite each other.
fn unique_names<'a>(names: impl IntoIterator<Item = &'a str>) -> Result<(), Error> {
    let mut seen = HashSet::new();
    for name in names {
        if !seen.insert(name) {
            return Err(Error::Invalid(format!(
                "two views share the image name {name:?}; their files would overwrite each other"
            )));
        }
    }
    Ok(())
}

/// The `views` list written to `request.json` (plain names).
pub fn view_entries(views: &[SourceView]) -> Result<Vec<ViewEntry>, Error> {
    for v in views {
        v.check()?;
    }
    let entries: Vec<ViewEntry> = views.iter().map(|v| entry(v.index, v.camera, None)).collect();
    unique_names(entries.iter().map(|e| e.name.as_str()))?;
    Ok(entries)
}

/// What [`export_views`] writes besides the images.
#[derive(Clone, Copy, Debug, Default)]
pub struct ExportSpec<'a> {
    /// The scene's [`fingerprint::scene`]: files get content names (plain without it).
    pub scene: Option<&'a str>,
    /// The shard these views are, recorded in `views.json`.
    pub shard: Option<Shard>,
    /// An earlier export whose content-named files are reused instead of rendered
    /// again, when its `views.json` records the same background.
    pub reuse: Option<&'a Path>,
    /// The render background, recorded in `views.json`.
    pub background: [f32; 3],
}

/// What [`export_views`] wrote.
#[derive(Clone, Debug)]
pub struct Exported {
    pub entries: Vec<ViewEntry>,
    /// Views copied from [`ExportSpec::reuse`] rather than rendered.
    pub reused: usize,
}

/// Writes one PNG per view and `views.json` (`{"scene", "shard", "views": [{"name",
/// "file", "index", "width", "height"}]}`) into `dir` (created if needed), rendering
/// one view at a time (a large scene's views never all sit in memory):
/// `image_of(k, index, camera)` returns view k's `H × W × 3` image. Every file is
/// written atomically.
pub fn export_views(
    cameras: &[(usize, &Camera)],
    dir: &Path,
    spec: ExportSpec,
    mut image_of: impl FnMut(usize, usize, &Camera) -> Result<Vec<f32>, Error>,
) -> Result<Exported, Error> {
    let entries: Vec<ViewEntry> = cameras.iter().map(|&(i, cam)| entry(i, cam, spec.scene)).collect();
    unique_names(entries.iter().map(|e| e.name.as_str()))?;
    std::fs::create_dir_all(dir).map_err(|e| transsplat_scene::Error::io(dir, e))?;
    let mut reused = 0;
    let reuse = spec.reuse.filter(|d| {
        spec.scene.is_some() && ViewsListing::read(d).is_some_and(|l| l.background == spec.background)
    });
    for (k, (&(index, cam), e)) in cameras.iter().zip(&entries).enumerate() {
        let earlier = reuse.map(|d| d.join(&e.file));
        if let Some(earlier) = earlier.filter(|p| p.is_file()) {
            std::fs::copy(&earlier, dir.join(&e.file))
                .map_err(|err| transsplat_scene::Error::io(&earlier, err))?;
            reused += 1;
            continue;
        }
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
    let listing = ViewsListing {
        scene: spec.scene.map(str::to_string),
        shard: spec.shard.map(|s| s.to_string()),
        background: spec.background,
        views: entries,
    };
    let text = serde_json::to_string_pretty(&listing).expect("plain data serialises");
    atomic::write_bytes(&dir.join(LISTING), text.as_bytes())?;
    Ok(Exported { entries: listing.views, reused })
}

/// The listing [`export_views`] writes beside the images.
pub const LISTING: &str = "views.json";

/// `views.json`: the exported views and what they were rendered for.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ViewsListing {
    /// The scene's [`fingerprint::scene`] when the files have content names.
    pub scene: Option<String>,
    /// The shard these views are (`I/N`), if sharded.
    pub shard: Option<String>,
    /// The render background.
    pub background: [f32; 3],
    pub views: Vec<ViewEntry>,
}

impl ViewsListing {
    /// The listing an earlier export left in `dir`, if it is there and readable.
    pub fn read(dir: &Path) -> Option<ViewsListing> {
        let text = std::fs::read(dir.join(LISTING)).ok()?;
        serde_json::from_slice(&text).ok()
    }
}

/// The shard recorded in an earlier export's `views.json` in `dir`, if any.
pub fn exported_shard(dir: &Path) -> Option<String> {
    ViewsListing::read(dir)?.shard
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn camera(name: &str, w: u32, h: u32) -> Camera {
        Camera::pinhole(name, w, h, 10.0)
    }

    /// Views of `cams` in order, all showing `src`.
    fn views_of<'a>(cams: &'a [Camera], src: &'a [f32]) -> Vec<SourceView<'a>> {
        cams.iter().enumerate().map(|(i, c)| SourceView { index: i, camera: c, image: src }).collect()
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
        let views = views_of(&cams, &src);
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

    /// `export_views` of in-memory images (the test's renders).
    fn export(views: &[SourceView], dir: &Path, spec: ExportSpec) -> Result<Exported, Error> {
        let cams: Vec<(usize, &Camera)> = views.iter().map(|v| (v.index, v.camera)).collect();
        export_views(&cams, dir, spec, |k, _, _| Ok(views[k].image.to_vec()))
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
        export(&views, &out, ExportSpec::default()).unwrap();
        let back = image::read(&out.join("0002.png")).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert!((back.data[0] - 0.8).abs() < 1.0 / 255.0);
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("views.json")).unwrap()).unwrap();
        assert_eq!(json["views"][0]["name"], "0001");
        assert_eq!(json["views"][1]["file"], "0002.png");
        assert_eq!(json["views"][1]["width"], 3);
        assert!(json["shard"].is_null() && json["scene"].is_null());
        // exported views read back unchanged give zero change attention
        let back = FolderEditor::new(&out).edit(&views, "").unwrap();
        assert!(back[0].as_ref().unwrap().attention.iter().all(|&a| a < 1e-6));
        // duplicate names are refused
        let dup = [views[0], views[0]];
        assert!(matches!(export(&dup, &out, ExportSpec::default()), Err(Error::Invalid(_))));
    }

    #[test]
    fn shards_parse_and_split_round_robin() {
        let s = Shard::parse("1/3").unwrap();
        assert_eq!((s.index, s.count, s.to_string()), (1, 3, "1/3".to_string()));
        let held: Vec<usize> = (0..8).filter(|&p| s.holds(p)).collect();
        assert_eq!(held, vec![1, 4, 7]);
        // every position in exactly one shard
        for p in 0..20 {
            assert_eq!((0..3).filter(|&i| Shard { index: i, count: 3 }.holds(p)).count(), 1);
        }
        for bad in ["3/3", "0/0", "1", "-1/3", "a/3", "1/x", "0/2000000"] {
            let e = Shard::parse(bad).unwrap_err();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn content_names_select_this_scenes_edits_from_shard_folders() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let cams = [camera("a.png", 4, 2), camera("b.png", 4, 2), camera("c.png", 4, 2)];
        let src = vec![0.0f32; 4 * 2 * 3];
        let views = views_of(&cams, &src);
        let (fp, other) = ("1".repeat(16), "2".repeat(16));
        // two shards exported, then "edited" in place: a + c in shard 0, b in shard 1
        let edited = d.join("edited");
        for (k, members) in [(0usize, [0usize, 2].as_slice()), (1, &[1])] {
            let shard = Shard { index: k, count: 2 };
            let part: Vec<SourceView> = members.iter().map(|&i| views[i]).collect();
            let spec = ExportSpec { scene: Some(&fp), shard: Some(shard), ..Default::default() };
            let done = export(&part, &edited.join(k.to_string()), spec).unwrap();
            assert_eq!(exported_shard(&edited.join(k.to_string())), Some(shard.to_string()));
            for e in &done.entries {
                let p = edited.join(k.to_string()).join(&e.file);
                grey_png(&p, 4, 2, |_, _| 0.1 * (e.index + 1) as f32);
            }
        }
        let name = content_name(&cams[1], Some(&fp));
        assert!(edited.join("1").join(format!("{name}.png")).is_file(), "{name}");
        let got = FolderEditor::new(&edited).for_scene(&fp).edit(&views, "").unwrap();
        for (i, g) in got.iter().enumerate() {
            let g = g.as_ref().unwrap();
            assert!((g.image[0] - 0.1 * (i + 1) as f32).abs() < 2.0 / 255.0, "view {i} from its shard");
        }
        // without the fingerprint the content names are not taken for plain ones
        assert!(matches!(FolderEditor::new(&edited).edit(&views, ""), Err(Error::NoEdits(_))));
        // another scene's files are refused by name, never used
        let e = FolderEditor::new(&edited).for_scene(&other).edit(&views, "").unwrap_err().to_string();
        assert!(e.contains("another scene") && e.contains(&edited.display().to_string()), "{e}");
        // one view edited in two shard folders is ambiguous
        let dup = edited.join("1").join(format!("{}.png", content_name(&cams[0], Some(&fp))));
        grey_png(&dup, 4, 2, |_, _| 0.9);
        let e = FolderEditor::new(&edited).for_scene(&fp).edit(&views, "").unwrap_err().to_string();
        assert!(e.contains("second edited image"), "{e}");
        std::fs::remove_file(&dup).unwrap();
        // a rerun reuses the earlier export's files instead of rendering them
        let again = d.join("again");
        let spec = ExportSpec { scene: Some(&fp), reuse: Some(&edited.join("0")), ..Default::default() };
        let done = export(&views, &again, spec).unwrap();
        assert_eq!(done.reused, 2, "a and c were in shard 0");
        // ... but not from an export on another background
        let white = ExportSpec { background: [1.0; 3], ..spec };
        assert_eq!(export(&views, &d.join("white"), white).unwrap().reused, 0);
        let a = image::read(&again.join(format!("{}.png", content_name(&cams[0], Some(&fp))))).unwrap();
        assert!((a.data[0] - 0.1).abs() < 2.0 / 255.0, "copied, not rendered");
        // a mask beside a content-named image is read under the same name
        let masks = again.join("masks");
        std::fs::create_dir(&masks).unwrap();
        grey_png(&masks.join(format!("{}.png", content_name(&cams[1], Some(&fp)))), 4, 2, |x, _| {
            x as f32 / 3.0
        });
        let got = FolderEditor::new(&again).for_scene(&fp).edit(&views, "").unwrap();
        assert_eq!(
            got[1].as_ref().unwrap().mask.as_deref(),
            Some(&[0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0][..])
        );
        assert!(got[0].as_ref().unwrap().mask.is_none());
    }
}

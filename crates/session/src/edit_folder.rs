//! The output folder of `transsplat edit`: the edited scene in the INRIA layout
//! (semantic latents as extra `sem_*` properties), before/after renders and gate heat
//! maps of the test views, per-round transport statistics and `report.html`.

use crate::heatmap::render_values;
use crate::report::Page;
use std::path::Path;
use transsplat_edit::EditConfig;
use transsplat_edit::{EditResult, RoundStats, StepLosses, Timing};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::formats::{self, SceneFormat};
use transsplat_scene::{atomic, cameras, image, ply, Camera, Gaussians};
use transsplat_viewer::{Layer, LayerKind, Role, Viewer};

/// File that marks a finished edit folder.
pub const MARKER: &str = "transport.json";

/// `transport.json`, the marker of a finished edit folder: what was asked, each
/// transport round's statistics, each step's losses and the timing by stage.
#[derive(Debug, serde::Serialize)]
pub struct EditSummary<'a> {
    pub prompt: &'a str,
    pub editor: &'a str,
    /// Where the masks came from, when a segmenter was attached to the editor.
    pub segmenter: Option<SegmenterSummary<'a>>,
    pub method: &'a str,
    pub rounds: &'a [RoundStats],
    pub losses: &'a [StepLosses],
    pub timing: &'a Timing,
    /// The Gaussians chosen as prototypes (indices into the source scene).
    pub prototypes: &'a [usize],
    /// Gaussians in the edited scene.
    pub gaussians: usize,
    /// The mean gate γ over the edited scene's Gaussians (methods with a gate).
    pub mean_gate: Option<f64>,
}

/// The segmenter of an edit in `transport.json`.
#[derive(Debug, serde::Serialize)]
pub struct SegmenterSummary<'a> {
    /// `clipseg`, `masks` (a folder of masks) or a Python segmenter's name.
    pub name: &'a str,
    /// What it was asked to segment (empty for a folder of masks).
    pub phrase: &'a str,
}

/// Everything `write` needs.
pub struct EditOutput<'a> {
    pub source: &'a Gaussians,
    pub result: &'a EditResult,
    pub cameras: &'a [Camera],
    pub test_views: &'a [usize],
    pub edit_views: &'a [usize],
    pub background: [f32; 3],
    pub prompt: &'a str,
    pub editor: &'a str,
    /// The segmenter's name and phrase, when one made the masks.
    pub segmenter: Option<(&'a str, &'a str)>,
    pub config: &'a EditConfig,
    /// Ground truth: which source Gaussians belong to the edit's target, where known.
    pub target: Option<&'a [bool]>,
    /// Formats written beside the PLY (`point_cloud.compressed.ply`, `.spz`).
    pub formats: &'a [SceneFormat],
    /// How they are written (SPZ's version and axes).
    pub write_options: formats::WriteOptions,
}

/// Writes the edit's outputs into `dir` (a staged folder).
pub fn write(dir: &Path, o: &EditOutput) -> Result<(), transsplat_scene::Error> {
    let r = o.result;
    let steps = o.config.schedule.steps;
    let pc = dir.join(format!("point_cloud/iteration_{steps}"));
    std::fs::create_dir_all(&pc).map_err(|e| transsplat_scene::Error::io(&pc, e))?;
    ply::write(&pc.join("point_cloud.ply"), &r.gaussians)?;
    for &f in o.formats.iter().filter(|&&f| f != SceneFormat::Ply) {
        formats::write_with(
            &pc.join(format!("point_cloud{}", f.extension())),
            &r.gaussians,
            f,
            &o.write_options,
        )?;
    }
    cameras::inria::write(&dir.join("cameras.json"), o.cameras)?;
    let rd = dir.join("renders");
    std::fs::create_dir_all(&rd).map_err(|e| transsplat_scene::Error::io(&rd, e))?;
    let opts = RenderOptions { background: o.background };
    let (before, after) = (Splats::new(o.source), Splats::new(&r.gaussians));
    let mut grid = Vec::new();
    for &v in o.test_views {
        let cam = &o.cameras[v];
        let (w, h) = (cam.width as usize, cam.height as usize);
        let stem = cam.stem();
        image::write_png(&rd.join(format!("before_{stem}.png")), w, h, &render(&before, cam, &opts).0.rgb)?;
        image::write_png(&rd.join(format!("after_{stem}.png")), w, h, &render(&after, cam, &opts).0.rgb)?;
        let mut cells = vec![
            ("before".to_string(), format!("renders/before_{stem}.png")),
            ("after".to_string(), format!("renders/after_{stem}.png")),
        ];
        if let Some(g) = &r.gate {
            image::write_png(
                &rd.join(format!("gate_{stem}.png")),
                w,
                h,
                &render_values(&r.gaussians, g, cam),
            )?;
            cells.push(("gate".to_string(), format!("renders/gate_{stem}.png")));
        }
        grid.push((stem, cells));
    }
    // The editor's 2D edits of a few views, with their attention and mask, for inspection.
    let mut edits = Vec::new();
    for (k, (e, &v)) in r.edited.iter().zip(o.edit_views).enumerate() {
        let Some(e) = e else { continue };
        if k % 4 != 0 {
            continue;
        }
        let stem = o.cameras[v].stem();
        image::write_png(&rd.join(format!("edited2d_{stem}.png")), e.width, e.height, &e.image)?;
        let amax = e.attention.iter().fold(0.0f32, |m, &a| m.max(a)).max(1e-12);
        let att: Vec<f32> = e.attention.iter().flat_map(|&a| [a / amax; 3]).collect();
        image::write_png(&rd.join(format!("attention_{stem}.png")), e.width, e.height, &att)?;
        let mut cells = vec![
            ("2D edit".to_string(), format!("renders/edited2d_{stem}.png")),
            ("attention".to_string(), format!("renders/attention_{stem}.png")),
        ];
        if let Some(mask) = &e.mask {
            let grey: Vec<f32> = mask.iter().flat_map(|&m| [m; 3]).collect();
            image::write_png(&rd.join(format!("mask_{stem}.png")), e.width, e.height, &grey)?;
            cells.push(("mask".to_string(), format!("renders/mask_{stem}.png")));
        }
        edits.push((stem.clone(), cells));
    }
    let stats = EditSummary {
        prompt: o.prompt,
        editor: o.editor,
        segmenter: o.segmenter.map(|(name, phrase)| SegmenterSummary { name, phrase }),
        method: o.config.method.name(),
        rounds: &r.rounds,
        losses: &r.losses,
        timing: &r.timing,
        prototypes: &r.prototypes,
        gaussians: r.gaussians.len(),
        mean_gate: r.gate.as_ref().map(|g| g.iter().map(|&x| x as f64).sum::<f64>() / g.len().max(1) as f64),
    };
    let mut p = Page::new(&format!("transsplat edit: \"{}\"", o.prompt));
    p.paragraph(&format!(
        "Editor {}, method {}, {} Gaussians, {:.1} s (editor {:.1} s, transport {:.1} s, optimisation {:.1} s).",
        o.editor,
        o.config.method.name(),
        r.gaussians.len(),
        r.timing.total,
        r.timing.editor,
        r.timing.transport,
        r.timing.optimise
    ));
    if let Some((name, phrase)) = o.segmenter {
        let what = if phrase.is_empty() { String::new() } else { format!(" of \"{phrase}\"") };
        p.paragraph(&format!(
            "Masks{what} from the segmenter ({name}): each edited view's support is its attention inside its mask."
        ));
    }
    p.heading("The edit in 3D");
    p.raw(&viewer_section(o)?);
    p.heading("Test views: before, after, gate");
    p.image_grid(&grid);
    p.heading("The editor's 2D edits, attention and mask (every 4th edit view)");
    p.image_grid(&edits);
    p.heading("Losses and transport statistics");
    let pts = |f: &dyn Fn(usize) -> (f64, f64), n: usize| (0..n).map(f).collect::<Vec<_>>();
    let l = &r.losses;
    p.plot(
        "losses per step",
        &[
            ("L_img".into(), pts(&|i| (l[i].step as f64, l[i].img), l.len())),
            ("L_leak".into(), pts(&|i| (l[i].step as f64, l[i].leak), l.len())),
            ("L_sem".into(), pts(&|i| (l[i].step as f64, l[i].sem), l.len())),
        ],
    );
    let rs = &r.rounds;
    p.plot(
        "transport objective and dual",
        &[
            ("objective".into(), pts(&|i| (rs[i].round as f64, rs[i].objective), rs.len())),
            ("dual".into(), pts(&|i| (rs[i].round as f64, rs[i].dual), rs.len())),
        ],
    );
    p.plot(
        "transported mass",
        &[("mass".into(), pts(&|i| (rs[i].round as f64, rs[i].transported_mass), rs.len()))],
    );
    p.plot("mean gate", &[("mean γ".into(), pts(&|i| (rs[i].round as f64, rs[i].mean_gate), rs.len()))]);
    p.heading("Settings");
    p.preformatted(&o.config.to_toml());
    atomic::write_bytes(&dir.join("report.html"), p.finish().as_bytes())?;
    atomic::write_bytes(&dir.join(MARKER), serde_json::to_string_pretty(&stats).expect("json").as_bytes())?;
    Ok(())
}

/// The report's 3D viewer: before and after, the cameras by role, and the gate, the
/// transported support and the ground-truth target as colour modes.
pub fn viewer_section(o: &EditOutput) -> Result<String, transsplat_scene::Error> {
    let r = o.result;
    let mut v = Viewer::new(
        &format!("\"{}\"", o.prompt),
        o.background,
        vec![("before".into(), o.source), ("after".into(), &r.gaussians)],
    );
    let n = r.gaussians.len();
    for (name, map) in [("gate γ", &r.gate), ("transported support", &r.support)] {
        if let Some(m) = map.as_ref().filter(|m| m.len() == n) {
            v.layers.push(Layer { name: name.into(), scene: 1, kind: LayerKind::Scalar, values: m.clone() });
        }
    }
    // The ground-truth target of whichever scene it was taken on.
    if let Some(t) = o.target {
        let scene = if t.len() == n { 1 } else { 0 };
        if t.len() == v.scenes[scene].1.len() {
            let values = t.iter().map(|&x| x as u8 as f32).collect();
            v.layers.push(Layer {
                name: "target (ground truth)".into(),
                scene,
                kind: LayerKind::Label,
                values,
            });
        }
    }
    v.cameras = o
        .cameras
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let role = if o.test_views.contains(&i) {
                Role::Test
            } else if o.edit_views.contains(&i) {
                Role::Edit
            } else {
                Role::Train
            };
            (c.clone(), role)
        })
        .collect();
    v.start_camera = o.test_views.first().copied().unwrap_or(0);
    transsplat_viewer::section(&v).map_err(|e| transsplat_scene::Error::format("report.html", e.to_string()))
}

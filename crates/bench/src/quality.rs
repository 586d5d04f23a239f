//! The ground-truth quality suite (`transsplat bench quality`): many demo cases, one
//! table. A case is a built-in scene (as built, or as trained from its own renders),
//! an instruction and a severity of the simulated editor; each runs every method
//! through [`crate::demo::run`] into its own folder (with its own `report.html`). The
//! suite writes `quality.json` (per case and averaged over the cases that ran),
//! `quality.md` (the same as a table), and `report.html` with plots of background and
//! target PSNR against severity per method. A case that fails (editor error, NaN,
//! anything) is reported as failed with its reason; the others still run.
//!
//! **Edits** ([`EDITS`], each at severities 0–3 of the simulated editor on the built
//! scene, and at severities 0 and 1 on the scene trained from its renders; with the
//! perfect edits of severity 0 a trained case checks that the edit is as faithful as
//! the trained scene allows: its target PSNR against the trained source's own target
//! PSNR on the unedited truth, the case's `source_fidelity`):
//!
//! | scene | kind | instruction | what it tests |
//! |---|---|---|---|
//! | tabletop | recolour | make the ball blue | the basic recolour |
//! | tabletop | far-recolour | make the cone black | a colour far from the original (green → black) |
//! | tabletop | material | turn the crate into marble | a texture, not a flat colour |
//! | tabletop | two-objects | make the ball and the cone blue | two objects at once |
//! | occluded | occluded | make the stem blue | a thin object in front of a busy backdrop |
//! | garden | far-recolour | make the apple cyan | red → its complement, beside a look-alike tomato, thin lamp and fence, a large far background |
//! | garden | global | make it autumn | a style of the whole scene (background included) that leakage suppression must not block |
//!
//! **Averages**: per method and per metric over the cases that ran and have a value:
//! a global edit has no background (its background PSNR is NaN, shown as "-") and is
//! left out of the background mean only. The worst methods of a case on a metric are
//! those at its lowest value among the methods with a value, ties included (naive and
//! no_leaksup are often identical); when every method has the same value none is worst.

use crate::capture::{self, Capture};
use crate::demo::{self, DemoError, DemoOptions, MethodScore};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use transsplat_edit::{EditConfig, Method, Progress};
use transsplat_scene::Gaussians;
use transsplat_session::report::{esc, Page};
use transsplat_session::views::ViewChoice;
use transsplat_session::Output;

/// Marker file of a finished suite folder.
pub const MARKER: &str = "quality.json";

/// One case of the suite.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Case {
    /// `scene-variant-edit-sN`, e.g. `tabletop-built-recolour-s1`.
    pub name: String,
    pub scene: String,
    /// Training steps from the scene's own renders (0: the built Gaussians).
    pub trained: u64,
    /// What kind of edit this is (`recolour`, `far-recolour`, `material`, `occluded`,
    /// `two-objects`, `global`).
    pub edit: String,
    pub prompt: String,
    pub severity: f32,
    /// A capture rendered from meshes (`--captures`; [`crate::capture`]) rather than a
    /// built-in scene.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub capture: Option<PathBuf>,
}

/// The suite's edits: (scene, kind, instruction); see the module doc.
pub const EDITS: &[(&str, &str, &str)] = &[
    ("tabletop", "recolour", "make the ball blue"),
    ("tabletop", "far-recolour", "make the cone black"),
    ("tabletop", "material", "turn the crate into marble"),
    ("tabletop", "two-objects", "make the ball and the cone blue"),
    ("occluded", "occluded", "make the stem blue"),
    ("garden", "far-recolour", "make the apple cyan"),
    ("garden", "global", "make it autumn"),
];

/// Severities of the trained variants: perfect edits (the fidelity check) and the
/// default demo's.
pub const TRAINED_SEVERITIES: [u32; 2] = [0, 1];

/// The cases: every edit at severities 0 to 3 on the built scenes, and at
/// [`TRAINED_SEVERITIES`] on the scenes trained from their renders (`trained_steps`) and
/// on each capture of `captures` trained for as many steps (none without them).
pub fn cases(trained_steps: u64, captures: &[Capture]) -> Vec<Case> {
    let mut out = Vec::new();
    for &(scene, edit, prompt) in EDITS {
        for s in 0..=3 {
            out.push(case(scene, 0, edit, prompt, s as f32));
        }
        if trained_steps > 0 {
            for s in TRAINED_SEVERITIES {
                out.push(case(scene, trained_steps, edit, prompt, s as f32));
            }
        }
    }
    if trained_steps > 0 {
        for c in captures {
            for s in TRAINED_SEVERITIES {
                let mut one = case(&c.name, trained_steps, CAPTURE_EDIT, &c.prompt(), s as f32);
                one.capture = Some(c.dir.clone());
                out.push(one);
            }
        }
    }
    out
}

/// The kind of a capture's edit: its target recoloured as the capture's true edit shows.
pub const CAPTURE_EDIT: &str = "capture-recolour";

fn case(scene: &str, trained: u64, edit: &str, prompt: &str, severity: f32) -> Case {
    let variant = if trained > 0 { "trained" } else { "built" };
    Case {
        name: format!("{scene}-{variant}-{edit}-s{severity}"),
        scene: scene.into(),
        trained,
        edit: edit.into(),
        prompt: prompt.into(),
        severity,
        capture: None,
    }
}

/// The cases named in `wanted` (in the suite's order); an unknown name is an error
/// listing every name.
pub fn select(all: Vec<Case>, wanted: &[String]) -> Result<Vec<Case>, String> {
    for w in wanted {
        if !all.iter().any(|c| &c.name == w) {
            let names: Vec<&str> = all.iter().map(|c| c.name.as_str()).collect();
            return Err(format!("unknown case {w:?}; the cases are: {}", names.join(", ")));
        }
    }
    Ok(all.into_iter().filter(|c| wanted.is_empty() || wanted.contains(&c.name)).collect())
}

/// Settings of a suite run.
#[derive(Clone, Debug)]
pub struct SuiteOptions {
    pub out: PathBuf,
    pub cases: Vec<Case>,
    /// Small scenes and the quick schedule (as `demo --quick`).
    pub quick: bool,
    pub methods: Vec<Method>,
    pub config: EditConfig,
    pub seed: u64,
    /// Which training views the simulated editor edits in every case (`--views`).
    pub views: ViewChoice,
    /// The captures of the capture cases (`--captures`).
    pub captures: Vec<Capture>,
    /// The simulated segmenter's severity on the built-in cases (`--segmenter`).
    pub segmenter: Option<f32>,
}

/// One case's outcome.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CaseResult {
    #[serde(flatten)]
    pub case: Case,
    /// Per method, when the case ran.
    pub scores: Vec<MethodScore>,
    /// A trained case's source against the unedited truth inside the target (dB): the
    /// bar of the edits' target PSNR (docs/method.md#m11-colour-clamp).
    pub source_fidelity: Option<f64>,
    /// A trained case at severity 0: the target PSNR of a scene trained the same way
    /// from the true edit's renders ([`crate::demo::Fidelity::retrained`]).
    pub retrained: Option<f64>,
    /// The editor's images against the true edit inside the target (dB), the evidence
    /// every method lifts.
    pub evidence_psnr: Option<f64>,
    /// Why the case failed, when it did.
    pub failed: Option<String>,
}

impl CaseResult {
    /// A case that failed, with the reason.
    pub fn failed(case: Case, why: String) -> Self {
        CaseResult {
            case,
            scores: Vec::new(),
            source_fidelity: None,
            retrained: None,
            evidence_psnr: None,
            failed: Some(why),
        }
    }
}

/// Runs the suite; `on_progress(case, method, progress)` reports progress.
pub fn run(
    opts: &SuiteOptions,
    cancel: Option<&AtomicBool>,
    on_progress: &mut dyn FnMut(&str, &str, Progress),
) -> Result<(PathBuf, Vec<CaseResult>), DemoError> {
    // The captures are inputs: the suite never writes into or over one.
    let inputs: Vec<&Path> = opts.captures.iter().map(|c| c.dir.as_path()).collect();
    let staged = Output::begin(&opts.out, &inputs, MARKER)?;
    let dir = staged.dir().to_path_buf();
    let mut results = Vec::new();
    // Each capture is trained once for all its cases.
    let mut trained_captures: Vec<(PathBuf, (Gaussians, f32))> = Vec::new();
    for c in &opts.cases {
        if cancel.is_some_and(|f| f.load(std::sync::atomic::Ordering::SeqCst)) {
            return Err(DemoError::Edit(transsplat_edit::EditError::Interrupted(0)));
        }
        let demo_opts = DemoOptions {
            out: dir.join(&c.name),
            scene: c.scene.clone(),
            prompt: c.prompt.clone(),
            severity: c.severity,
            quick: opts.quick,
            methods: opts.methods.clone(),
            config: opts.config.clone(),
            seed: opts.seed,
            trained: c.trained,
            // Perfect edits: how close can an edit of this trained scene come?
            retrain_truth: c.trained > 0 && c.severity == 0.0 && c.capture.is_none(),
            views: opts.views,
            segmenter: opts.segmenter,
        };
        let outcome = match &c.capture {
            None => demo::run(&demo_opts, cancel, &mut |m, p| on_progress(&c.name, m, p)),
            Some(path) => {
                run_capture(opts, path, c, &mut trained_captures, &demo_opts, cancel, &mut |m, p| {
                    on_progress(&c.name, m, p)
                })
            }
        };
        let r = match outcome {
            Ok(d) => CaseResult {
                case: c.clone(),
                scores: d.scores,
                source_fidelity: d.trained.map(|f| f.target_psnr),
                retrained: d.trained.and_then(|f| f.retrained),
                evidence_psnr: Some(d.evidence_psnr),
                failed: None,
            },
            Err(DemoError::Edit(e @ transsplat_edit::EditError::Interrupted(_))) => {
                return Err(DemoError::Edit(e));
            }
            Err(e) => {
                tracing::warn!("case {} failed: {e}", c.name);
                CaseResult::failed(c.clone(), e.to_string())
            }
        };
        results.push(r);
    }
    let summary = averages(&results);
    let json = SuiteSummary { cases: &results, averages: &summary };
    let write = || -> Result<(), DemoError> {
        transsplat_scene::atomic::write_bytes(&dir.join("quality.md"), table(&results, &summary).as_bytes())?;
        write_report(&dir, &results, &summary)?;
        let text = serde_json::to_string_pretty(&json).expect("plain data serialises");
        Ok(transsplat_scene::atomic::write_bytes(&dir.join(MARKER), text.as_bytes())?)
    };
    // A failed write names the output the user gave, not the staging folder.
    write().map_err(|e| match e {
        DemoError::Io(e) => DemoError::Io(staged.user_error(e)),
        e => e,
    })?;
    Ok((staged.commit()?, results))
}

/// A capture case: trains the capture (once per suite run) and edits it.
fn run_capture(
    opts: &SuiteOptions,
    path: &Path,
    case: &Case,
    trained: &mut Vec<(PathBuf, (Gaussians, f32))>,
    demo_opts: &DemoOptions,
    cancel: Option<&AtomicBool>,
    on_progress: &mut dyn FnMut(&str, Progress),
) -> Result<demo::DemoOutcome, DemoError> {
    let capture = opts
        .captures
        .iter()
        .find(|c| c.dir == path)
        .ok_or_else(|| DemoError::Capture(format!("the capture {} was not loaded", path.display())))?;
    if !trained.iter().any(|(p, _)| p == path) {
        let g = capture::train(capture, case.trained, opts.seed, cancel, &mut |s, n| {
            on_progress("train", Progress::Step { step: s as usize, steps: n as usize, loss: 0.0 })
        })?;
        trained.push((path.to_path_buf(), g));
    }
    let (_, g) = trained.iter().find(|(p, _)| p == path).expect("trained above");
    capture::run(capture, g, demo_opts, cancel, on_progress)
}

/// `quality.json`, the marker of a finished suite folder: every case's scores and the
/// per-method averages.
#[derive(Debug, serde::Serialize)]
pub struct SuiteSummary<'a> {
    pub cases: &'a [CaseResult],
    pub averages: &'a std::collections::BTreeMap<String, Average>,
}

/// Per-method means over the cases that ran; each metric over the cases where it has
/// a (finite) value, counted separately.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Average {
    /// Cases that ran.
    pub cases: usize,
    /// Mean target PSNR over `target_cases` cases.
    pub target_psnr: f64,
    pub target_cases: usize,
    /// Mean background PSNR over `background_cases` cases (a global edit has none).
    pub background_psnr: f64,
    pub background_cases: usize,
    /// Mean over the same cases of the worst test view's background PSNR.
    pub background_psnr_worst: f64,
    /// Mean silhouette PSNR (the band about the target's outline, both sides) over
    /// `silhouette_cases` cases (a global edit has none).
    pub silhouette_psnr: f64,
    pub silhouette_cases: usize,
    /// Over the cases with a gate.
    pub gate_auroc: Option<f64>,
    /// Cases where this method has the lowest target PSNR, background PSNR or worst
    /// view's background PSNR of all the methods with a value (every method tied at the
    /// lowest counts; none when all tie).
    pub worst_cases: usize,
}

/// The methods at the lowest finite value of `f` in `scores`: every method tied there,
/// and none when every method with a value has the same one (nobody is worse).
fn worst(scores: &[MethodScore], f: fn(&MethodScore) -> f64) -> Vec<&str> {
    let values: Vec<f64> = scores.iter().map(f).filter(|v| v.is_finite()).collect();
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    if values.iter().all(|&v| v == lo) {
        return Vec::new();
    }
    scores.iter().filter(|s| f(s) == lo).map(|s| s.name.as_str()).collect()
}

/// The per-method averages of the cases that ran.
pub fn averages(results: &[CaseResult]) -> BTreeMap<String, Average> {
    let mut out: BTreeMap<String, Average> = BTreeMap::new();
    let mut aurocs: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for r in results.iter().filter(|r| r.failed.is_none()) {
        let worst_t = worst(&r.scores, |s| s.metrics.target_psnr);
        let worst_b = worst(&r.scores, |s| s.metrics.background_psnr);
        let worst_view = worst(&r.scores, |s| s.metrics.background_psnr_worst);
        for s in &r.scores {
            let a = out.entry(s.name.clone()).or_default();
            a.cases += 1;
            if s.metrics.target_psnr.is_finite() {
                a.target_psnr += s.metrics.target_psnr;
                a.target_cases += 1;
            }
            if s.metrics.silhouette_psnr.is_finite() {
                a.silhouette_psnr += s.metrics.silhouette_psnr;
                a.silhouette_cases += 1;
            }
            if s.metrics.background_psnr.is_finite() {
                a.background_psnr += s.metrics.background_psnr;
                a.background_psnr_worst += s.metrics.background_psnr_worst;
                a.background_cases += 1;
            }
            if [&worst_t, &worst_b, &worst_view].iter().any(|w| w.contains(&s.name.as_str())) {
                a.worst_cases += 1;
            }
            if let Some(g) = s.gate_auroc.filter(|g| g.is_finite()) {
                aurocs.entry(s.name.clone()).or_default().push(g);
            }
        }
    }
    let mean = |sum: f64, n: usize| if n == 0 { f64::NAN } else { sum / n as f64 };
    for (name, a) in out.iter_mut() {
        a.target_psnr = mean(a.target_psnr, a.target_cases);
        a.background_psnr = mean(a.background_psnr, a.background_cases);
        a.background_psnr_worst = mean(a.background_psnr_worst, a.background_cases);
        a.silhouette_psnr = mean(a.silhouette_psnr, a.silhouette_cases);
        a.gate_auroc = aurocs.get(name).map(|v| v.iter().sum::<f64>() / v.len() as f64);
    }
    out
}

/// A PSNR with two decimals, "-" when it is not a number.
fn db(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.2}")
    } else {
        "-".into()
    }
}

/// The suite as Markdown: one row per case and method, then the averages.
pub fn table(results: &[CaseResult], avg: &BTreeMap<String, Average>) -> String {
    let mut s = String::from(
        "| case | method | target PSNR | background PSNR | background, worst view | silhouette PSNR | gate AUROC |\n|---|---|---|---|---|---|---|\n",
    );
    for r in results {
        if let Some(why) = &r.failed {
            s += &format!(
                "| {} | **failed** | {} | | | | |\n",
                r.case.name,
                why.replace('|', "\\|").replace('\n', " ")
            );
            continue;
        }
        for m in &r.scores {
            s += &format!(
                "| {} | {} | {} | {} | {} | {} | {} |\n",
                r.case.name,
                m.name,
                db(m.metrics.target_psnr),
                db(m.metrics.background_psnr),
                db(m.metrics.background_psnr_worst),
                db(m.metrics.silhouette_psnr),
                m.gate_auroc.map_or("-".into(), |a| format!("{a:.4}"))
            );
        }
    }
    s += &fidelity_table(results);
    s += &ceiling_table(results);
    s += "\n| method | cases | mean target PSNR (cases) | mean background PSNR (cases) | mean worst-view background PSNR | mean silhouette PSNR (cases) | mean gate AUROC | worst on a case |\n|---|---|---|---|---|---|---|---|\n";
    for (name, a) in avg {
        s += &format!(
            "| {name} | {} | {} ({}) | {} ({}) | {} | {} ({}) | {} | {} |\n",
            a.cases,
            db(a.target_psnr),
            a.target_cases,
            db(a.background_psnr),
            a.background_cases,
            db(a.background_psnr_worst),
            db(a.silhouette_psnr),
            a.silhouette_cases,
            a.gate_auroc.map_or("-".into(), |g| format!("{g:.4}")),
            a.worst_cases
        );
    }
    s
}

/// The trained cases' target PSNR against their source's fidelity (target PSNR minus
/// fidelity, per method), with the target PSNR of the scene retrained from the true
/// edit where there is one, as Markdown; empty without trained cases.
pub fn fidelity_table(results: &[CaseResult]) -> String {
    let trained: Vec<&CaseResult> =
        results.iter().filter(|r| r.failed.is_none() && r.source_fidelity.is_some()).collect();
    let Some(first) = trained.first() else { return String::new() };
    let names: Vec<&str> = first.scores.iter().map(|m| m.name.as_str()).collect();
    let mut s = format!(
        "\nTrained cases: each method's target PSNR minus the trained source's own target PSNR \
         against the unedited truth (the edit's bar), and the target PSNR of a scene trained the same \
         way from the true edit's renders (severity 0)\n\n| case | source's target PSNR | \
         retrained on the true edit | {} |\n|---|---|---|{}\n",
        names.join(" | "),
        "---|".repeat(names.len())
    );
    for r in trained {
        let f = r.source_fidelity.unwrap_or(f64::NAN);
        let gaps: Vec<String> = names
            .iter()
            .map(|n| {
                r.scores.iter().find(|m| m.name == *n).map_or("-".into(), |m| {
                    let g = m.metrics.target_psnr - f;
                    if g.is_finite() {
                        format!("{g:+.2}")
                    } else {
                        "-".into()
                    }
                })
            })
            .collect();
        s += &format!(
            "| {} | {} | {} | {} |\n",
            r.case.name,
            db(f),
            db(r.retrained.unwrap_or(f64::NAN)),
            gaps.join(" | ")
        );
    }
    s
}

/// The method whose target PSNR with perfect edits is the ceiling of a trained scene:
/// the image loss alone, every Gaussian free.
pub const CEILING_METHOD: &str = "naive";

/// The trained cases against their ceiling: `naive` fed the uncorrupted edits of the
/// same trained scene (the severity-0 case of the same scene and edit). Per method, its
/// target PSNR minus the ceiling; and the default's distance to the best method of the
/// case. As Markdown; empty without trained cases that have a ceiling.
pub fn ceiling_table(results: &[CaseResult]) -> String {
    let ran: Vec<&CaseResult> = results.iter().filter(|r| r.failed.is_none() && r.case.trained > 0).collect();
    let ceiling_of = |c: &Case| {
        ran.iter()
            .find(|r| {
                r.case.severity == 0.0
                    && (&r.case.scene, r.case.trained, &r.case.edit) == (&c.scene, c.trained, &c.edit)
            })
            .and_then(|r| r.scores.iter().find(|m| m.name == CEILING_METHOD))
            .map(|m| m.metrics.target_psnr)
            .filter(|v| v.is_finite())
    };
    let rows: Vec<(&CaseResult, f64)> = ran.iter().filter_map(|r| Some((*r, ceiling_of(&r.case)?))).collect();
    let Some((first, _)) = rows.first() else { return String::new() };
    let names: Vec<&str> = first.scores.iter().map(|m| m.name.as_str()).collect();
    let mut s = format!(
        "\nTrained cases against the ceiling ({CEILING_METHOD} fed the uncorrupted edits of the same \
         trained scene): each method's target PSNR minus the ceiling, and the default's distance \
         to the best method of the case; the 2D evidence is the editor's images against the true edit \
         inside the target\n\n| case | ceiling | 2D evidence | {} | default − best |\n|---|---|---|{}---|\n",
        names.join(" | "),
        "---|".repeat(names.len())
    );
    for (r, ceiling) in rows {
        let target = |n: &str| r.scores.iter().find(|m| m.name == n).map(|m| m.metrics.target_psnr);
        let gaps: Vec<String> = names
            .iter()
            .map(|n| {
                target(n).filter(|t| t.is_finite()).map_or("-".into(), |t| format!("{:+.2}", t - ceiling))
            })
            .collect();
        let best =
            r.scores.iter().map(|m| m.metrics.target_psnr).filter(|v| v.is_finite()).fold(f64::NAN, f64::max);
        let to_best = target(Method::Transsplat.name()).map_or("-".into(), |t| db(t - best));
        let evidence = r.evidence_psnr.map_or("-".into(), db);
        s += &format!(
            "| {} | {} | {evidence} | {} | {to_best} |\n",
            r.case.name,
            db(ceiling),
            gaps.join(" | ")
        );
    }
    s
}

fn write_report(
    dir: &Path,
    results: &[CaseResult],
    avg: &BTreeMap<String, Average>,
) -> Result<(), DemoError> {
    let mut p = Page::new("transsplat quality suite");
    p.paragraph(&format!(
        "{} cases ({} failed). Each case's folder has its own report.html with every method's edit and 3D viewer.",
        results.len(),
        results.iter().filter(|r| r.failed.is_some()).count()
    ));
    p.heading("Averages over the cases that ran");
    let rows: Vec<Vec<String>> = avg
        .iter()
        .map(|(n, a)| {
            vec![
                n.clone(),
                a.cases.to_string(),
                format!("{} ({})", db(a.target_psnr), a.target_cases),
                format!("{} ({})", db(a.background_psnr), a.background_cases),
                db(a.background_psnr_worst),
                a.gate_auroc.map_or("-".into(), |g| format!("{g:.4}")),
                a.worst_cases.to_string(),
            ]
        })
        .collect();
    p.table(
        &[
            "method",
            "cases",
            "target PSNR (cases)",
            "background PSNR (cases)",
            "background, worst view",
            "gate AUROC",
            "worst on a case",
        ],
        &rows,
    );
    // Per edit (built scenes): PSNR against severity, one line per method.
    let mut edits: Vec<(String, String)> = Vec::new();
    for r in results {
        let key = (r.case.scene.clone(), r.case.edit.clone());
        if r.case.trained == 0 && !edits.contains(&key) {
            edits.push(key);
        }
    }
    for (scene, edit) in &edits {
        let of_edit: Vec<&CaseResult> = results
            .iter()
            .filter(|r| {
                &r.case.scene == scene && &r.case.edit == edit && r.case.trained == 0 && r.failed.is_none()
            })
            .collect();
        let series = |f: fn(&MethodScore) -> f64| -> Vec<(String, Vec<(f64, f64)>)> {
            let mut by: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
            for r in &of_edit {
                for s in &r.scores {
                    by.entry(s.name.clone()).or_default().push((r.case.severity as f64, f(s)));
                }
            }
            by.into_iter().collect()
        };
        p.plot(
            &format!("{scene}, {edit}: background PSNR against severity"),
            &series(|s| s.metrics.background_psnr),
        );
        p.plot(&format!("{scene}, {edit}: target PSNR against severity"), &series(|s| s.metrics.target_psnr));
    }
    p.heading("Cases");
    let rows: Vec<Vec<String>> = results
        .iter()
        .map(|r| {
            let best = |f: fn(&MethodScore) -> f64| {
                r.scores
                    .iter()
                    .filter(|s| f(s).is_finite())
                    .max_by(|a, b| f(a).total_cmp(&f(b)))
                    .map_or("-".into(), |s| s.name.clone())
            };
            vec![
                r.case.name.clone(),
                esc(&r.case.prompt),
                r.failed.clone().map_or_else(|| "ran".into(), |w| format!("failed: {w}")),
                best(|s| s.metrics.background_psnr),
                best(|s| s.metrics.target_psnr),
            ]
        })
        .collect();
    p.table(&["case", "instruction", "outcome", "best background", "best target"], &rows);
    p.preformatted(&table(results, avg));
    transsplat_scene::atomic::write_bytes(&dir.join("report.html"), p.finish().as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_eval::ground_truth::GtMetrics;

    fn score(name: &str, t: f64, b: f64) -> MethodScore {
        MethodScore {
            name: name.into(),
            metrics: GtMetrics {
                target_psnr: t,
                background_psnr: b,
                background_psnr_worst: b,
                // a global edit (no background) has no outline either
                silhouette_psnr: b,
                ..Default::default()
            },
            gate_auroc: None,
            seconds: 0.0,
            transport_seconds: 0.0,
        }
    }

    /// A case that ran, built-in (no fidelity).
    fn ran(case: Case, scores: Vec<MethodScore>) -> CaseResult {
        CaseResult { case, scores, source_fidelity: None, retrained: None, evidence_psnr: None, failed: None }
    }

    #[test]
    fn unknown_case_names_are_an_error_listing_the_cases() {
        let e = select(cases(0, &[]), &["nope".into()]).unwrap_err();
        assert!(e.contains("unknown case \"nope\"") && e.contains("tabletop-built-recolour-s1"), "{e}");
        let one = select(cases(0, &[]), &["occluded-built-occluded-s2".into()]).unwrap();
        assert_eq!(one.len(), 1);
        assert_eq!(select(cases(0, &[]), &[]).unwrap().len(), 28);
        assert_eq!(cases(500, &[]).len(), 42);
        assert!(select(cases(500, &[]), &["garden-trained-global-s0".into()]).is_ok());
        let e = select(cases(0, &[]), &["garden-built-global-s1".into(), "garden-built-global-s9".into()])
            .unwrap_err();
        assert!(e.contains("\"garden-built-global-s9\"") && e.contains("garden-built-global-s3"), "{e}");
    }

    #[test]
    fn the_edits_cover_three_scenes_and_six_kinds_and_each_parses_on_its_scene() {
        use transsplat_builtin::simulated::parse_instruction;
        use transsplat_builtin::{build, SceneConfig};
        let mut scenes: Vec<&str> = EDITS.iter().map(|e| e.0).collect();
        scenes.dedup();
        let mut kinds: Vec<&str> = EDITS.iter().map(|e| e.1).collect();
        kinds.sort_unstable();
        kinds.dedup();
        assert_eq!(scenes, ["tabletop", "occluded", "garden"]);
        assert_eq!(kinds, ["far-recolour", "global", "material", "occluded", "recolour", "two-objects"]);
        for &(scene, kind, prompt) in EDITS {
            let s = build(scene, &SceneConfig::quick()).unwrap();
            let ins = parse_instruction(&s, prompt).unwrap_or_else(|e| panic!("{scene}: {prompt:?}: {e}"));
            assert_eq!(ins.is_global(), kind == "global", "{prompt:?}");
            assert_eq!(
                ins.objects.len(),
                if kind == "two-objects" { 2 } else { (kind != "global") as usize }
            );
        }
    }

    #[test]
    fn nan_values_are_left_out_of_their_metric_only() {
        let c = cases(0, &[]);
        let global = c.iter().find(|c| c.edit == "global").unwrap().clone();
        let results = vec![
            ran(c[0].clone(), vec![score("a", 30.0, 40.0), score("b", 20.0, 50.0)]),
            ran(global, vec![score("a", 10.0, f64::NAN), score("b", 14.0, f64::NAN)]),
        ];
        let avg = averages(&results);
        assert_eq!((avg["a"].cases, avg["a"].target_cases, avg["a"].background_cases), (2, 2, 1));
        assert_eq!(avg["a"].target_psnr, 20.0);
        assert_eq!(avg["a"].background_psnr, 40.0, "the global case has no background");
        assert_eq!(avg["b"].background_psnr, 50.0);
        // a: worst target in the global case, worst background in case 0 (counted once
        // per case); b: worst target in case 0; no one is worst on a NaN background
        assert_eq!((avg["a"].worst_cases, avg["b"].worst_cases), (2, 1));
        let t = table(&results, &avg);
        assert!(t.contains("| garden-built-global-s0 | a | 10.00 | - | - | - | - |"), "{t}");
        assert!(t.contains("| a | 2 | 20.00 (2) | 40.00 (1) | 40.00 | 40.00 (1) | - | 2 |"), "{t}");
        // a method without any value shows "-"
        let only_nan = vec![ran(c[1].clone(), vec![score("a", f64::NAN, f64::NAN)])];
        let avg = averages(&only_nan);
        assert!(avg["a"].target_psnr.is_nan() && avg["a"].worst_cases == 0);
        assert!(table(&only_nan, &avg).contains("| a | 1 | - (0) | - (0) | - | - (0) | - | 0 |"));
        // ties: both methods at the lowest value are worst; when all tie, none is
        let tied = vec![ran(
            c[1].clone(),
            vec![score("a", 20.0, 30.0), score("b", 20.0, 35.0), score("c", 25.0, 30.0)],
        )];
        let avg = averages(&tied);
        assert_eq!([avg["a"].worst_cases, avg["b"].worst_cases, avg["c"].worst_cases], [1, 1, 1]);
        let all_tie = vec![ran(c[1].clone(), vec![score("a", 20.0, 30.0), score("b", 20.0, 30.0)])];
        let avg = averages(&all_tie);
        assert_eq!((avg["a"].worst_cases, avg["b"].worst_cases), (0, 0));
    }

    #[test]
    fn a_leak_in_one_view_counts_as_worst_though_the_mean_is_best() {
        let c = cases(0, &[]);
        let mut leaky = score("a", 30.0, 50.0);
        leaky.metrics.background_psnr_worst = 34.0;
        let results = vec![ran(c[0].clone(), vec![leaky, score("b", 30.0, 45.0)])];
        let avg = averages(&results);
        assert_eq!((avg["a"].worst_cases, avg["b"].worst_cases), (1, 1));
        assert_eq!((avg["a"].background_psnr_worst, avg["b"].background_psnr_worst), (34.0, 45.0));
    }

    #[test]
    fn averages_skip_failed_cases_and_count_worst_places() {
        let c = cases(0, &[]);
        let results = vec![
            ran(c[0].clone(), vec![score("a", 30.0, 40.0), score("b", 20.0, 50.0)]),
            ran(c[1].clone(), vec![score("a", 10.0, 20.0), score("b", 12.0, 30.0)]),
            CaseResult::failed(c[2].clone(), "editor error".into()),
        ];
        let avg = averages(&results);
        assert_eq!(avg["a"].cases, 2);
        assert_eq!(avg["a"].target_psnr, 20.0);
        assert_eq!(avg["b"].background_psnr, 40.0);
        // a: worst background in case 0, worst both in case 1; b: worst target in case 0.
        assert_eq!((avg["a"].worst_cases, avg["b"].worst_cases), (2, 1));
        let t = table(&results, &avg);
        assert!(t.contains("| tabletop-built-recolour-s2 | **failed** | editor error |"), "{t}");
    }

    #[test]
    fn trained_cases_show_each_method_against_the_source_fidelity() {
        let c = cases(500, &[]);
        let trained = c.iter().find(|c| c.trained > 0 && c.severity == 0.0).unwrap().clone();
        let results = vec![
            ran(c[0].clone(), vec![score("a", 30.0, 40.0), score("b", 20.0, 50.0)]),
            CaseResult {
                case: trained,
                scores: vec![score("a", 31.5, 40.0), score("b", 34.25, 50.0)],
                source_fidelity: Some(33.0),
                retrained: Some(35.5),
                evidence_psnr: None,
                failed: None,
            },
        ];
        let t = fidelity_table(&results);
        assert!(t.contains("| case | source's target PSNR | retrained on the true edit | a | b |"), "{t}");
        assert!(t.contains("| tabletop-trained-recolour-s0 | 33.00 | 35.50 | -1.50 | +1.25 |"), "{t}");
        assert!(!t.contains("built"), "built cases have no fidelity row: {t}");
        assert_eq!(fidelity_table(&results[..1]), "");
        assert!(table(&results, &averages(&results)).contains(&t));
    }

    #[test]
    fn trained_cases_are_measured_against_naive_with_perfect_edits() {
        let c = cases(500, &[]);
        let find = |sev: f32| {
            c.iter()
                .find(|c| c.trained > 0 && c.edit == "recolour" && c.scene == "tabletop" && c.severity == sev)
                .unwrap()
                .clone()
        };
        let results = vec![
            ran(c[0].clone(), vec![score("transsplat", 30.0, 40.0), score("naive", 20.0, 50.0)]),
            ran(find(0.0), vec![score("transsplat", 33.0, 40.0), score("naive", 34.0, 50.0)]),
            CaseResult {
                evidence_psnr: Some(18.25),
                ..ran(find(1.0), vec![score("transsplat", 25.5, 40.0), score("naive", 26.0, 50.0)])
            },
        ];
        let t = ceiling_table(&results);
        assert!(t.contains("| case | ceiling | 2D evidence | transsplat | naive | default − best |"), "{t}");
        assert!(t.contains("| tabletop-trained-recolour-s0 | 34.00 | - | -1.00 | +0.00 | -1.00 |"), "{t}");
        assert!(
            t.contains("| tabletop-trained-recolour-s1 | 34.00 | 18.25 | -8.50 | -8.00 | -0.50 |"),
            "{t}"
        );
        assert!(!t.contains("built"), "built cases have no ceiling: {t}");
        assert_eq!(ceiling_table(&results[..1]), "");
        assert!(table(&results, &averages(&results)).contains(&t));
    }
}

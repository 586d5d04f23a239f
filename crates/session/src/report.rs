//! A small self-contained HTML report builder: tables, image grids (relative paths)
//! and inline SVG line plots. Used by `transsplat demo` and `transsplat edit`.

use std::fmt::Write;

/// An HTML page under construction.
#[derive(Default)]
pub struct Page {
    body: String,
    title: String,
}

/// HTML-escapes text.
pub use transsplat_viewer::escape as esc;

const COLOURS: [&str; 8] =
    ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"];

impl Page {
    pub fn new(title: &str) -> Self {
        let mut p = Page { title: title.to_string(), ..Default::default() };
        let _ = writeln!(p.body, "<h1>{}</h1>", esc(title));
        p
    }

    pub fn heading(&mut self, text: &str) {
        let _ = writeln!(self.body, "<h2>{}</h2>", esc(text));
    }

    /// Appends HTML as is (a section built by another crate, e.g. the 3D viewer).
    pub fn raw(&mut self, html: &str) {
        self.body.push_str(html);
    }

    pub fn paragraph(&mut self, text: &str) {
        let _ = writeln!(self.body, "<p>{}</p>", esc(text));
    }

    pub fn preformatted(&mut self, text: &str) {
        let _ = writeln!(self.body, "<pre>{}</pre>", esc(text));
    }

    /// A table with a header row.
    pub fn table(&mut self, header: &[&str], rows: &[Vec<String>]) {
        let mut s = String::from("<table><tr>");
        for h in header {
            let _ = write!(s, "<th>{}</th>", esc(h));
        }
        s.push_str("</tr>");
        for r in rows {
            s.push_str("<tr>");
            for c in r {
                let _ = write!(s, "<td>{}</td>", esc(c));
            }
            s.push_str("</tr>");
        }
        s.push_str("</table>");
        self.body.push_str(&s);
    }

    /// Rows of captioned images (`src` relative to the report).
    pub fn image_grid(&mut self, rows: &[(String, Vec<(String, String)>)]) {
        let mut s = String::from("<table class=grid>");
        for (label, cells) in rows {
            let _ = write!(s, "<tr><th>{}</th>", esc(label));
            for (caption, src) in cells {
                let _ = write!(
                    s,
                    "<td><img src=\"{}\" alt=\"{}\"><br>{}</td>",
                    esc(src),
                    esc(caption),
                    esc(caption)
                );
            }
            s.push_str("</tr>");
        }
        s.push_str("</table>");
        self.body.push_str(&s);
    }

    /// An SVG line plot of named series of (x, y) points.
    pub fn plot(&mut self, title: &str, series: &[(String, Vec<(f64, f64)>)]) {
        let (w, h, m) = (560.0, 220.0, 40.0);
        let pts = series.iter().flat_map(|(_, p)| p.iter()).filter(|(x, y)| x.is_finite() && y.is_finite());
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for &(x, y) in pts {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
        if x0 > x1 {
            return;
        }
        if x1 - x0 < 1e-12 {
            x1 = x0 + 1.0;
        }
        if y1 - y0 < 1e-12 {
            y1 = y0 + 1.0;
        }
        let sx = |x: f64| m + (x - x0) / (x1 - x0) * (w - 2.0 * m);
        let sy = |y: f64| h - m + (y0 - y) / (y1 - y0) * (h - 2.0 * m);
        let mut s = format!(
            "<figure><figcaption>{}</figcaption><svg width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\">",
            esc(title)
        );
        let _ = write!(
            s,
            "<rect x=\"{m}\" y=\"{m}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"#999\"/>",
            w - 2.0 * m,
            h - 2.0 * m
        );
        let _ = write!(s, "<text x=\"2\" y=\"{}\" font-size=\"10\">{:.3e}</text><text x=\"2\" y=\"{}\" font-size=\"10\">{:.3e}</text>", m + 4.0, y1, h - m, y0);
        let _ = write!(s, "<text x=\"{m}\" y=\"{}\" font-size=\"10\">{x0}</text><text x=\"{}\" y=\"{}\" font-size=\"10\">{x1}</text>", h - m + 14.0, w - m - 20.0, h - m + 14.0);
        for (k, (name, p)) in series.iter().enumerate() {
            let c = COLOURS[k % COLOURS.len()];
            let path: Vec<String> = p
                .iter()
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .map(|&(x, y)| format!("{:.1},{:.1}", sx(x), sy(y)))
                .collect();
            let _ = write!(
                s,
                "<polyline fill=\"none\" stroke=\"{c}\" stroke-width=\"1.5\" points=\"{}\"/>",
                path.join(" ")
            );
            let _ = write!(
                s,
                "<text x=\"{}\" y=\"{}\" font-size=\"11\" fill=\"{c}\">{}</text>",
                w - m + 4.0 - 120.0,
                m + 14.0 + 13.0 * k as f64,
                esc(name)
            );
        }
        s.push_str("</svg></figure>");
        self.body.push_str(&s);
    }

    /// The finished document.
    pub fn finish(self) -> String {
        format!(
            "<!doctype html><html><head><meta charset=\"utf-8\"><title>{}</title><style>\
             body{{font-family:sans-serif;margin:2em;max-width:1400px}}table{{border-collapse:collapse;margin:1em 0}}\
             td,th{{border:1px solid #ccc;padding:4px 8px;text-align:center;font-size:13px}}\
             .grid img{{max-width:220px;image-rendering:pixelated}}pre{{background:#f6f6f6;padding:1em;font-size:12px}}\
             figure{{display:inline-block;margin:0.5em}}</style></head><body>\n{}\n</body></html>\n",
            esc(&self.title),
            self.body
        )
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn escapes_and_contains_the_parts() {
        let mut p = super::Page::new("a <b> & c");
        p.table(&["x"], &[vec!["<1>".into()]]);
        p.plot("loss", &[("m".into(), vec![(0.0, 1.0), (1.0, 0.5)])]);
        let html = p.finish();
        assert!(
            html.contains("a &lt;b&gt; &amp; c") && html.contains("&lt;1&gt;") && html.contains("<polyline")
        );
    }
}

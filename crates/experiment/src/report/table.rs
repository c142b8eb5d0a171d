//! The paper's Table II layout: one row per method, PSNR / SSIM / LPIPS for every scene and their
//! average over scenes; values are means over seeds (± the standard deviation when there are
//! several). Also the margins between two methods and a time table.

use crate::results::Row;
use crate::suite::Suite;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// One (scene, method) entry: means over seeds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Entry {
    pub psnr: f64,
    pub ssim: f64,
    pub lpips: Option<f64>,
    pub wall_s: f64,
    /// Standard deviation of the PSNR over seeds (None for one seed).
    pub psnr_sd: Option<f64>,
    pub seeds: usize,
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// The mean rows (`channel == mean`) of one method on one scene, over seeds.
pub fn entry(rows: &[&Row]) -> Option<Entry> {
    let r: Vec<&&Row> = rows
        .iter()
        .filter(|r| r.channel == "mean" && r.psnr.is_some())
        .collect();
    if r.is_empty() {
        return None;
    }
    let psnr: Vec<f64> = r.iter().filter_map(|r| r.psnr).collect();
    let lp: Vec<f64> = r.iter().filter_map(|r| r.lpips).collect();
    let m = mean(&psnr);
    Some(Entry {
        psnr: m,
        ssim: mean(&r.iter().filter_map(|r| r.ssim).collect::<Vec<_>>()),
        lpips: (lp.len() == r.len()).then(|| mean(&lp)),
        wall_s: mean(&r.iter().map(|r| r.wall_s).collect::<Vec<_>>()),
        psnr_sd: (psnr.len() > 1).then(|| {
            (psnr.iter().map(|p| (p - m).powi(2)).sum::<f64>() / (psnr.len() - 1) as f64).sqrt()
        }),
        seeds: r.len(),
    })
}

/// Methods × scenes.
#[derive(Clone, Debug, Default)]
pub struct Table {
    /// `(key, label)` in study order.
    pub scenes: Vec<(String, String)>,
    pub methods: Vec<(String, String)>,
    pub entries: BTreeMap<(String, String), Entry>,
}

impl Table {
    /// The table of `rows` (one study, one views / noise group) for `scenes` × `methods`.
    pub fn new(suite: &Suite, scenes: &[String], methods: &[String], rows: &[&Row]) -> Self {
        let mut entries = BTreeMap::new();
        for s in scenes {
            for m in methods {
                let sel: Vec<&Row> = rows
                    .iter()
                    .filter(|r| &r.scene == s && &r.method == m && r.variant.is_empty())
                    .copied()
                    .collect();
                if let Some(e) = entry(&sel) {
                    entries.insert((s.clone(), m.clone()), e);
                }
            }
        }
        let label = |f: &dyn Fn(&str) -> String, v: &[String]| {
            v.iter().map(|k| (k.clone(), f(k))).collect()
        };
        Table {
            scenes: label(&|k| suite.scene_label(k).to_string(), scenes),
            methods: label(&|k| suite.method_label(k).to_string(), methods),
            entries,
        }
    }

    pub fn get(&self, scene: &str, method: &str) -> Option<&Entry> {
        self.entries.get(&(scene.to_string(), method.to_string()))
    }

    /// The average over scenes of a method (None unless every scene has an entry).
    pub fn average(&self, method: &str) -> Option<Entry> {
        let e: Vec<&Entry> = self
            .scenes
            .iter()
            .map(|(s, _)| self.get(s, method))
            .collect::<Option<_>>()?;
        let lp: Vec<f64> = e.iter().filter_map(|x| x.lpips).collect();
        Some(Entry {
            psnr: mean(&e.iter().map(|x| x.psnr).collect::<Vec<_>>()),
            ssim: mean(&e.iter().map(|x| x.ssim).collect::<Vec<_>>()),
            lpips: (lp.len() == e.len()).then(|| mean(&lp)),
            wall_s: e.iter().map(|x| x.wall_s).sum(),
            psnr_sd: None,
            seeds: e.iter().map(|x| x.seeds).min().unwrap_or(0),
        })
    }

    /// Table II: a row per method; PSNR↑ / SSIM↑ / LPIPS↓ per scene and on average; the best
    /// value of every column in bold.
    pub fn markdown(&self) -> String {
        let mut cols: Vec<(String, Vec<Option<Entry>>)> = self
            .scenes
            .iter()
            .map(|(k, l)| {
                let v = self.methods.iter().map(|(m, _)| self.get(k, m).copied());
                (l.clone(), v.collect())
            })
            .collect();
        cols.push((
            "Average".into(),
            self.methods.iter().map(|(m, _)| self.average(m)).collect(),
        ));
        let mut s = String::from("| Method |");
        for (l, _) in &cols {
            let _ = write!(s, " {l} PSNR↑ | SSIM↑ | LPIPS↓ |");
        }
        s.push_str("\n|---|");
        s.push_str(&"---:|".repeat(cols.len() * 3));
        s.push('\n');
        for (i, (_, label)) in self.methods.iter().enumerate() {
            let _ = write!(s, "| {label} |");
            for (_, v) in &cols {
                let best = |f: &dyn Fn(&Entry) -> Option<f64>, high: bool| {
                    let vals: Vec<f64> = v.iter().flatten().filter_map(f).collect();
                    let b = if high {
                        vals.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
                    } else {
                        vals.iter().cloned().fold(f64::INFINITY, f64::min)
                    };
                    v[i].as_ref()
                        .and_then(f)
                        .is_some_and(|x| x == b && vals.len() > 1)
                };
                match &v[i] {
                    Some(e) => {
                        let sd = e.psnr_sd.map_or(String::new(), |d| format!(" ± {d:.2}"));
                        let bold = |t: String, b: bool| if b { format!("**{t}**") } else { t };
                        let _ = write!(
                            s,
                            " {} | {} | {} |",
                            bold(format!("{:.2}{sd}", e.psnr), best(&|e| Some(e.psnr), true)),
                            bold(format!("{:.4}", e.ssim), best(&|e| Some(e.ssim), true)),
                            match e.lpips {
                                Some(l) => bold(format!("{l:.4}"), best(&|e| e.lpips, false)),
                                None => "–".into(),
                            }
                        );
                    }
                    None => s.push_str(" – | – | – |"),
                }
            }
            s.push('\n');
        }
        s
    }

    /// Seconds of every method on every scene and their sum.
    pub fn times_markdown(&self) -> String {
        let mut s = String::from("| Method |");
        for (_, l) in &self.scenes {
            let _ = write!(s, " {l} |");
        }
        s.push_str(" total |\n|---|");
        s.push_str(&"---:|".repeat(self.scenes.len() + 1));
        s.push('\n');
        for (m, label) in &self.methods {
            let _ = write!(s, "| {label} |");
            for (k, _) in &self.scenes {
                match self.get(k, m) {
                    Some(e) => {
                        let _ = write!(s, " {} |", seconds(e.wall_s));
                    }
                    None => s.push_str(" – |"),
                }
            }
            match self.average(m) {
                Some(a) => {
                    let _ = writeln!(s, " {} |", seconds(a.wall_s));
                }
                None => s.push_str(" – |\n"),
            }
        }
        s
    }

    /// `a` against `b` on every scene and on average: the PSNR and SSIM differences and the time
    /// ratio a / b.
    pub fn margins_markdown(&self, a: &str, b: &str) -> Option<String> {
        let la = &self.methods.iter().find(|m| m.0 == a)?.1;
        let lb = &self.methods.iter().find(|m| m.0 == b)?.1;
        let mut s = format!(
            "| Scene | {la} PSNR | {lb} PSNR | Δ PSNR (dB) | Δ SSIM | time {la} / {lb} |\n|---|---:|---:|---:|---:|---:|\n"
        );
        let mut rows: Vec<(String, Option<Entry>, Option<Entry>)> = self
            .scenes
            .iter()
            .map(|(k, l)| (l.clone(), self.get(k, a).copied(), self.get(k, b).copied()))
            .collect();
        rows.push(("**Average**".into(), self.average(a), self.average(b)));
        for (label, ea, eb) in rows {
            match (ea, eb) {
                (Some(x), Some(y)) => {
                    let _ = writeln!(
                        s,
                        "| {label} | {:.2} | {:.2} | {:+.2} | {:+.4} | {:.2}× |",
                        x.psnr,
                        y.psnr,
                        x.psnr - y.psnr,
                        x.ssim - y.ssim,
                        x.wall_s / y.wall_s
                    );
                }
                _ => {
                    let _ = writeln!(s, "| {label} | – | – | – | – | – |");
                }
            }
        }
        Some(s)
    }
}

/// Seconds for tables: `12.3` below a minute, `4 min 05 s` above.
pub fn seconds(s: f64) -> String {
    if s < 59.95 {
        format!("{s:.1} s")
    } else {
        // Whole seconds first, so 119.7 s is 2 min 00 s, not 1 min 60 s.
        let whole = s.round() as u64;
        format!("{} min {:02} s", whole / 60, whole % 60)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(scene: &str, method: &str, seed: u64, psnr: f64, wall: f64) -> Row {
        Row {
            study: "t".into(),
            scene: scene.into(),
            scene_label: scene.into(),
            views: 13,
            noise: "shipped".into(),
            seed,
            method: method.into(),
            method_label: method.into(),
            variant: String::new(),
            channel: "mean".into(),
            held_out: false,
            psnr: Some(psnr),
            ssim: Some(psnr / 100.0),
            psnr_slices: None,
            ssim_slices: None,
            lpips: None,
            proj_psnr: None,
            proj_ssim: None,
            wall_s: wall,
            channels: 3,
            run_dir: String::new(),
        }
    }

    #[test]
    fn the_table_averages_seeds_and_scenes_and_marks_the_best() {
        let suite: Suite = serde_yaml_ng::from_str(
            "name: t\nscenes: {a: {config: a.yaml, label: Chest}, b: {config: b.yaml}}\nmethods: {x: {config: x.yaml}, y: {config: y.yaml}}\nstudies: []\n",
        )
        .unwrap();
        let rows = [
            row("a", "x", 0, 30.0, 10.0),
            row("a", "x", 1, 32.0, 12.0),
            row("a", "y", 0, 29.0, 100.0),
            row("b", "x", 0, 40.0, 20.0),
            row("b", "y", 0, 41.0, 50.0),
        ];
        let refs: Vec<&Row> = rows.iter().collect();
        let keys = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let t = Table::new(&suite, &keys(&["a", "b"]), &keys(&["x", "y"]), &refs);
        let ax = t.get("a", "x").unwrap();
        assert_eq!((ax.psnr, ax.wall_s, ax.seeds), (31.0, 11.0, 2));
        assert!((ax.psnr_sd.unwrap() - 2f64.sqrt()).abs() < 1e-12);
        let avg = t.average("x").unwrap();
        assert_eq!((avg.psnr, avg.wall_s), (35.5, 31.0));
        let md = t.markdown();
        assert!(md.contains("| Chest PSNR↑ | SSIM↑ | LPIPS↓ |"), "{md}");
        assert!(
            md.contains("**31.00 ± 1.41**") && md.contains("**41.00**"),
            "{md}"
        );
        assert!(md.contains("**35.50**"), "average column: {md}");
        let margins = t.margins_markdown("x", "y").unwrap();
        assert!(
            margins.contains("| Chest | 31.00 | 29.00 | +2.00 |"),
            "{margins}"
        );
        assert!(
            margins.contains("| b | 40.00 | 41.00 | -1.00 |"),
            "{margins}"
        );
        assert!(margins.contains("0.21×"), "time ratio 31/150: {margins}");
        assert_eq!(seconds(125.0), "2 min 05 s");
        assert_eq!(seconds(119.7), "2 min 00 s");
        assert_eq!(seconds(59.97), "1 min 00 s");
        assert_eq!(seconds(59.9), "59.9 s");
    }
}

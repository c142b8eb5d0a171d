//! The plain-text description of a scene that `prism info` prints.

use super::Scene;
use crate::geometry::Beam;
use ndarray::{ArrayView3, Axis};
use std::fmt::Write;

/// (min, max, mean) of an iterator of values; `None` when it is empty.
fn stats(values: impl Iterator<Item = f32>) -> Option<(f32, f32, f64)> {
    let (mut lo, mut hi, mut sum, mut n) = (f32::INFINITY, f32::NEG_INFINITY, 0.0f64, 0usize);
    for x in values {
        lo = lo.min(x);
        hi = hi.max(x);
        sum += f64::from(x);
        n += 1;
    }
    (n > 0).then(|| (lo, hi, sum / n as f64))
}

/// A length or distance with at most 4 decimals and no trailing zeros (`5.3333`, `1000`).
fn mm(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

fn fmt_stats(s: Option<(f32, f32, f64)>) -> [String; 3] {
    match s {
        Some((lo, hi, mean)) => [format!("{lo:.4}"), format!("{hi:.4}"), format!("{mean:.4}")],
        None => ["-".into(), "-".into(), "-".into()],
    }
}

/// Left-aligned columns separated by two spaces, each line indented by two.
fn table(rows: &[Vec<String>]) -> String {
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0);
    let width: Vec<usize> = (0..cols)
        .map(|c| {
            rows.iter()
                .filter_map(|r| r.get(c))
                .map(|s| s.chars().count())
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut out = String::new();
    for r in rows {
        let line: Vec<String> = r
            .iter()
            .enumerate()
            .map(|(c, s)| format!("{s:<w$}", w = width[c]))
            .collect();
        let _ = writeln!(out, "  {}", line.join("  ").trim_end());
    }
    out
}

fn kv(rows: &[(&str, String)]) -> String {
    table(
        &rows
            .iter()
            .map(|(k, v)| vec![k.to_string(), v.clone()])
            .collect::<Vec<_>>(),
    )
}

impl Scene {
    /// A plain-text, column-aligned summary: geometry, channels, availability and value ranges
    /// (projection statistics are over the views where the channel is available).
    pub fn summary(&self) -> String {
        let g = &self.geometry;
        let d = &g.detector;
        let vg = &g.volume;
        let [sx, sy, sz] = vg.size();
        let deg: Vec<f64> = g.angles_rad.iter().map(|a| a.to_degrees()).collect();
        let (amin, amax) = deg
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &a| {
                (lo.min(a), hi.max(a))
            });
        let mut out = format!("scene `{}`\n\ngeometry\n", self.name);
        out += &kv(&[
            (
                "beam",
                match (g.beam, g.is_circular()) {
                    (Beam::Cone, true) => "cone".into(),
                    (Beam::Parallel, true) => "parallel".into(),
                    (b, false) => format!(
                        "{}, per-view vectors (the distances, pitches and angles below are \
                         nominal)",
                        if b == Beam::Cone { "cone" } else { "parallel" }
                    ),
                },
            ),
            (
                "DSO / DSD",
                format!(
                    "{} / {} mm (magnification {:.4})",
                    mm(g.dso),
                    mm(g.dsd),
                    g.magnification()
                ),
            ),
            (
                "detector",
                format!(
                    "{} rows × {} cols, pitch {} × {} mm (u × v), offset ({}, {}) mm (u, v)",
                    d.rows,
                    d.cols,
                    mm(d.pitch_u),
                    mm(d.pitch_v),
                    mm(d.offset_u),
                    mm(d.offset_v)
                ),
            ),
            (
                "volume",
                format!(
                    "{} × {} × {} voxels (x × y × z) of {} × {} × {} mm, size {} × {} × {} mm, \
                     offset ({}, {}, {}) mm",
                    vg.nx,
                    vg.ny,
                    vg.nz,
                    mm(vg.dx),
                    mm(vg.dy),
                    mm(vg.dz),
                    mm(sx),
                    mm(sy),
                    mm(sz),
                    mm(vg.offset[0]),
                    mm(vg.offset[1]),
                    mm(vg.offset[2])
                ),
            ),
            (
                "views",
                format!(
                    "{} from {amin:.2}° to {amax:.2}° (span {:.2}°); {} train, {} test",
                    g.views(),
                    amax - amin,
                    self.split.train.len(),
                    self.split.test.len()
                ),
            ),
        ]);

        out += "\nchannels\n";
        let mut rows = vec![
            [
                "#",
                "label",
                "coordinate",
                "tau",
                "views",
                "train",
                "test",
                "proj min",
                "proj max",
                "proj mean",
                "ref min",
                "ref max",
                "ref mean",
            ]
            .map(String::from)
            .to_vec(),
        ];
        for (c, ch) in self.channels.iter().enumerate() {
            let views = self.views_with_channel(c);
            let count = |list: &[usize]| list.iter().filter(|v| views.contains(v)).count();
            let proj: ArrayView3<f32> = self.channel_projections(c);
            let p = stats(
                views
                    .iter()
                    .flat_map(|&v| proj.index_axis(Axis(0), v).into_iter().copied()),
            );
            let r = self
                .references
                .as_ref()
                .and_then(|r| stats(r.index_axis(Axis(0), c).iter().copied()));
            let mut row = vec![
                c.to_string(),
                ch.label.clone(),
                ch.coordinate.to_string(),
                format!("{:.4}", ch.tau),
                views.len().to_string(),
                count(&self.split.train).to_string(),
                count(&self.split.test).to_string(),
            ];
            row.extend(fmt_stats(p));
            row.extend(fmt_stats(r));
            rows.push(row);
        }
        out += &table(&rows);
        out += "  (projections: line integrals over the available views; references: μ in mm⁻¹)\n";
        if let Some(s) = &self.structural {
            let [lo, hi, mean] = fmt_stats(stats(s.iter().copied()));
            let _ = writeln!(
                out,
                "\nstructural (full-spectrum) projections\n  min {lo}  max {hi}  mean {mean}"
            );
        }
        let p = &self.provenance;
        let mut prov: Vec<(&str, String)> = Vec::new();
        for (k, v) in [("generator", &p.generator), ("created by", &p.created_by)] {
            if !v.is_empty() {
                prov.push((k, v.clone()));
            }
        }
        if let Some(a) = &p.axis {
            prov.push(("rotation axis", a.describe()));
        }
        for s in &p.source_data {
            prov.push(("source", s.clone()));
        }
        for s in &p.licence {
            prov.push(("licence", s.clone()));
        }
        if !prov.is_empty() {
            out += "\nprovenance\n";
            out += &kv(&prov);
        }
        out
    }
}

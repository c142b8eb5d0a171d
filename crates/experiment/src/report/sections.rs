//! One report section per study kind: its tables and its charts.

use super::pictures;
use super::table::{Table, seconds};
use super::timing;
use super::{Context, label, mean_row};
use crate::Result;
use crate::figures::charts::{Bars, Lines, Panel, Series};
use crate::figures::plot::save;
use crate::results::Row;
use crate::suite::StudyKind;
use prism_recon::Method;
use std::fmt::Write as _;

/// The (views, noise) groups of study `i`, in axis order.
fn groups(ctx: &Context, i: usize) -> Vec<(usize, String)> {
    let mut g: Vec<(usize, String)> = Vec::new();
    for p in &ctx.plan.studies[i].points {
        let k = (p.views, p.noise.clone());
        if !g.contains(&k) {
            g.push(k);
        }
    }
    g
}

/// The methods of study `i` that are `m`, in study order.
fn all_of(ctx: &Context, i: usize, m: Method) -> Vec<String> {
    ctx.plan.studies[i]
        .spec
        .methods
        .iter()
        .filter(|k| ctx.plan.methods.get(*k) == Some(&m))
        .cloned()
        .collect()
}

/// Table II per (views, noise) group, margins, equal-time comparison, PSNR against wall time
/// and slice montages (`table`); the same tables per noise level and PSNR against the noise
/// level (`noise`).
pub(crate) fn table(ctx: &mut Context, i: usize) -> Result<String> {
    let spec = ctx.plan.studies[i].spec.clone();
    let suite = &ctx.loaded.suite;
    let rows = ctx.study_rows(&spec.name);
    let four = all_of(ctx, i, Method::FourDsg);
    let r2 = all_of(ctx, i, Method::R2gs).into_iter().next();
    let mut md = String::new();
    let groups = groups(ctx, i);
    for (views, noise) in &groups {
        let sel: Vec<&Row> = rows
            .iter()
            .filter(|r| r.views == *views && &r.noise == noise)
            .copied()
            .collect();
        let t = Table::new(suite, &spec.scenes, &spec.methods, &sel);
        let _ = writeln!(md, "### {views} views, noise `{noise}`\n\n{}", t.markdown());
        let _ = writeln!(md, "Training time:\n\n{}", t.times_markdown());
        md.push_str(&timing::time_to_quality(ctx, i, *views, noise));
        for a in &four {
            if let Some(b) = &r2
                && let Some(m) = t.margins_markdown(a, b)
            {
                let _ = writeln!(md, "{} against {}:\n\n{m}", label(ctx, a), label(ctx, b));
                md.push_str(&timing::equal_time(ctx, i, *views, noise, a, b));
            }
        }
        if spec.kind == StudyKind::Table {
            md.push_str(&timing::psnr_time(ctx, i, *views, noise)?);
            for scene in &spec.scenes {
                md.push_str(&pictures::slices(ctx, i, *views, noise, scene)?);
            }
        }
        md.push_str(&per_channel(ctx, &sel));
    }
    if spec.kind == StudyKind::Noise && spec.noise.len() > 1 {
        md.push_str(&noise_chart(ctx, i, &rows)?);
    }
    Ok(md)
}

/// Per-channel PSNR of every run in `sel` (collapsed).
fn per_channel(ctx: &Context, sel: &[&Row]) -> String {
    let mut md = String::from(
        "<details><summary>PSNR (dB) per channel</summary>\n\n| Scene | Method | Seed | Channels |\n|---|---|---:|---|\n",
    );
    let mut seen = Vec::new();
    for r in sel
        .iter()
        .filter(|r| r.channel == "mean" && r.variant.is_empty())
    {
        let key = (&r.scene, &r.method, r.seed);
        if seen.contains(&key) {
            continue;
        }
        seen.push(key);
        let chans: Vec<String> = sel
            .iter()
            .filter(|c| {
                c.scene == r.scene
                    && c.method == r.method
                    && c.seed == r.seed
                    && c.channel != "mean"
            })
            .map(|c| {
                format!(
                    "{}{} {:.2}",
                    c.channel,
                    if c.held_out { " (held out)" } else { "" },
                    c.psnr.unwrap_or(f64::NAN)
                )
            })
            .collect();
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} |",
            r.scene_label,
            label(ctx, &r.method),
            r.seed,
            chans.join(", ")
        );
    }
    md.push_str("\n</details>\n\n");
    md
}

/// PSNR against the noise level, a panel per scene.
fn noise_chart(ctx: &mut Context, i: usize, rows: &[&Row]) -> Result<String> {
    let spec = ctx.plan.studies[i].spec.clone();
    let levels: Vec<String> = spec.noise.iter().map(|n| n.name.clone()).collect();
    let ticks: Vec<(f64, String)> = levels
        .iter()
        .enumerate()
        .map(|(k, l)| (k as f64, l.clone()))
        .collect();
    let mut panels = Vec::new();
    for scene in &spec.scenes {
        let series = spec
            .methods
            .iter()
            .map(|m| {
                let pts = levels
                    .iter()
                    .enumerate()
                    .filter_map(|(k, n)| {
                        let sel: Vec<&Row> = rows
                            .iter()
                            .filter(|r| &r.scene == scene && &r.method == m && &r.noise == n)
                            .copied()
                            .collect();
                        super::table::entry(&sel).map(|e| (k as f64, e.psnr))
                    })
                    .collect();
                Series {
                    markers: true,
                    ..Series::line(label(ctx, m), ctx.colour(m), pts)
                }
            })
            .collect();
        panels.push(Panel {
            title: ctx.loaded.suite.scene_label(scene).to_string(),
            x_label: "noise level".into(),
            y_label: "mean PSNR (dB)".into(),
            log_x: false,
            log_y: false,
            series,
            x_ticks: Some(ticks.clone()),
        });
    }
    let fig = Lines {
        title: "PSNR against the noise of the training projections".into(),
        cols: panels.len().clamp(1, 3),
        panel: (440, 330),
        panels,
    };
    let paths = save(&ctx.figure_stem(&format!("{}-psnr-noise", spec.name)), &fig)?;
    Ok(ctx.embed(paths, "PSNR against the noise level (means over seeds)"))
}

/// A point of the channel study: (channels, wall seconds, PSNR).
type ChannelPoint = (usize, f64, f64);

/// Training time and PSNR against the number of channels.
pub(crate) fn channels(ctx: &mut Context, i: usize) -> Result<String> {
    let st = ctx.plan.studies[i].clone();
    let rows = ctx.study_rows(&st.spec.name);
    let mut by_method: Vec<(String, Vec<ChannelPoint>)> = Vec::new();
    for m in &st.spec.methods {
        let mut pts: Vec<ChannelPoint> = Vec::new();
        for p in st.points.iter().filter(|p| &p.method == m) {
            if let Some(r) = mean_row(&rows, p) {
                pts.push((
                    ctx.plan.scene_of(p.run).channels,
                    r.wall_s,
                    r.psnr.unwrap_or(f64::NAN),
                ));
            }
        }
        pts.sort_by_key(|q| q.0);
        by_method.push((m.clone(), pts));
    }
    let counts: Vec<usize> = {
        let mut c: Vec<usize> = by_method
            .iter()
            .flat_map(|m| m.1.iter().map(|q| q.0))
            .collect();
        c.sort_unstable();
        c.dedup();
        c
    };
    let mut md = String::from("| Method |");
    for c in &counts {
        let _ = write!(md, " {c} ch: time | PSNR |");
    }
    md.push_str("\n|---|");
    md.push_str(&"---:|".repeat(counts.len() * 2));
    md.push('\n');
    for (m, pts) in &by_method {
        let _ = write!(md, "| {} |", label(ctx, m));
        for c in &counts {
            match pts.iter().find(|q| q.0 == *c) {
                Some(q) => {
                    let _ = write!(md, " {} | {:.2} |", seconds(q.1), q.2);
                }
                None => md.push_str(" – | – |"),
            }
        }
        md.push('\n');
    }
    let r2 = all_of(ctx, i, Method::R2gs).into_iter().next();
    let pairs: Vec<(String, String)> = all_of(ctx, i, Method::FourDsg)
        .into_iter()
        .filter_map(|a| r2.clone().map(|b| (a, b)))
        .collect();
    md.push('\n');
    for (a, b) in pairs {
        let time = |k: &str, c: usize| {
            by_method
                .iter()
                .find(|m| m.0 == k)
                .and_then(|m| m.1.iter().find(|q| q.0 == c))
                .map(|q| q.1)
        };
        let _ = write!(md, "Time ratio {} / {}:", label(ctx, &a), label(ctx, &b));
        for c in &counts {
            if let (Some(x), Some(y)) = (time(&a, *c), time(&b, *c)) {
                let _ = write!(md, " {c} channels {:.2}×;", x / y);
            }
        }
        md.push_str("\n\n");
    }
    let series = |f: fn(&(usize, f64, f64)) -> f64| -> Vec<Series> {
        by_method
            .iter()
            .map(|(m, pts)| Series {
                markers: true,
                ..Series::line(
                    label(ctx, m),
                    ctx.colour(m),
                    pts.iter().map(|q| (q.0 as f64, f(q))).collect(),
                )
            })
            .collect()
    };
    let ticks: Vec<(f64, String)> = counts.iter().map(|&c| (c as f64, c.to_string())).collect();
    let fig = Lines {
        title: "Training time and PSNR against the number of channels".into(),
        cols: 2,
        panel: (480, 360),
        panels: vec![
            Panel {
                title: "training time".into(),
                x_label: "channels".into(),
                y_label: "seconds".into(),
                series: series(|q| q.1),
                x_ticks: Some(ticks.clone()),
                ..Panel::default()
            },
            Panel {
                title: "mean PSNR".into(),
                x_label: "channels".into(),
                y_label: "dB".into(),
                series: series(|q| q.2),
                x_ticks: Some(ticks),
                ..Panel::default()
            },
        ],
    };
    let paths = save(
        &ctx.figure_stem(&format!("{}-time-channels", st.spec.name)),
        &fig,
    )?;
    md.push_str(&ctx.embed(
        paths,
        "Training time and PSNR against the number of channels",
    ));
    Ok(md)
}

/// Stage-2 ablations: a table per cell (variants) and bar charts.
pub(crate) fn ablation(ctx: &mut Context, i: usize) -> Result<String> {
    let st = ctx.plan.studies[i].clone();
    let rows = ctx.study_rows(&st.spec.name);
    let mut md = String::new();
    let mut variants: Vec<String> = Vec::new();
    for r in rows
        .iter()
        .filter(|r| r.channel == "mean" && !r.variant.is_empty())
    {
        if !variants.contains(&r.variant) {
            variants.push(r.variant.clone());
        }
    }
    for scene in &st.spec.scenes {
        let scene_label = ctx.loaded.suite.scene_label(scene).to_string();
        let mut bars: Vec<(String, usize, Vec<Option<f64>>)> = Vec::new();
        for (g, (views, noise)) in groups(ctx, i).iter().enumerate() {
            let sel: Vec<&Row> = rows
                .iter()
                .filter(|r| {
                    &r.scene == scene
                        && r.views == *views
                        && &r.noise == noise
                        && r.channel == "mean"
                })
                .copied()
                .collect();
            let _ = writeln!(
                md,
                "### {scene_label}, {views} views, noise `{noise}`\n\n| Variant | PSNR | SSIM | time |\n|---|---:|---:|---:|"
            );
            let mut vals = Vec::new();
            for v in &variants {
                let vr: Vec<&Row> = sel.iter().filter(|r| &r.variant == v).copied().collect();
                let e = super::table::entry(&vr);
                match e {
                    Some(e) => {
                        let _ = writeln!(
                            md,
                            "| {v} | {:.2} | {:.4} | {} |",
                            e.psnr,
                            e.ssim,
                            seconds(e.wall_s)
                        );
                    }
                    None => {
                        let _ = writeln!(md, "| {v} | – | – | – |");
                    }
                }
                vals.push(e.map(|e| e.psnr));
            }
            md.push('\n');
            bars.push((format!("{views} views, {noise}"), g, vals));
        }
        // Freeze: variants along x, one bar per group; curve model: groups along x.
        let fig = if st.spec.kind == StudyKind::CurveModel {
            Bars {
                title: format!("{scene_label}: curve model by view count"),
                y_label: "mean PSNR (dB)".into(),
                categories: bars.iter().map(|b| b.0.clone()).collect(),
                series: variants
                    .iter()
                    .enumerate()
                    .map(|(k, v)| (v.clone(), k, bars.iter().map(|b| b.2[k]).collect()))
                    .collect(),
                size: (640, 400),
            }
        } else {
            Bars {
                title: format!("{scene_label}: stage-2 freezing strategies (P R S D)"),
                y_label: "mean PSNR (dB)".into(),
                categories: variants.iter().map(|v| v.replace("PRSD-", "")).collect(),
                series: bars,
                size: (760, 400),
            }
        };
        let paths = save(&ctx.figure_stem(&format!("{}-{scene}", st.spec.name)), &fig)?;
        md.push_str(&ctx.embed(
            paths,
            &format!("{}: {scene_label} (means over seeds)", st.spec.kind.name()),
        ));
    }
    Ok(md)
}

/// Channels held out of training: their scores beside the fitted ones, and their projections.
pub(crate) fn holdout(ctx: &mut Context, i: usize) -> Result<String> {
    let st = ctx.plan.studies[i].clone();
    let rows = ctx.study_rows(&st.spec.name);
    let mut md = String::from(
        "| Scene | Method | Seed | Channel | volume PSNR | SSIM | projection PSNR | SSIM | fitted channels' mean PSNR |\n|---|---|---:|---|---:|---:|---:|---:|---:|\n",
    );
    let f = |v: Option<f64>, d: usize| v.map_or("–".into(), |v| format!("{v:.d$}"));
    for p in &st.points {
        let mean = mean_row(&rows, p).and_then(|r| r.psnr);
        for r in rows.iter().filter(|r| {
            r.held_out
                && r.scene == p.scene
                && r.method == p.method
                && r.seed == p.seed
                && r.views == p.views
                && r.noise == p.noise
        }) {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.scene_label,
                label(ctx, &r.method),
                r.seed,
                r.channel,
                f(r.psnr, 2),
                f(r.ssim, 4),
                f(r.proj_psnr, 2),
                f(r.proj_ssim, 4),
                f(mean, 2)
            );
        }
    }
    md.push('\n');
    let seed = st.spec.seeds[0];
    for p in st.points.iter().filter(|p| p.seed == seed) {
        md.push_str(&pictures::holdout(ctx, p)?);
    }
    Ok(md)
}

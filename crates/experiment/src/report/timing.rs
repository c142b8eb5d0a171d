//! Training time against quality, per (views, noise) group of a table study: both methods at
//! equal wall time, each method's time to 95 % and 99 % of its last PSNR, and PSNR against
//! training time.

use super::table::seconds;
use super::{Context, label, mean_row, point};
use crate::Result;
use crate::curve::Curve;
use crate::figures::charts::{Lines, Panel, Series};
use crate::figures::plot::save;
use crate::plan::StudyPoint;
use crate::results::Row;
use std::fmt::Write as _;

/// Both methods at the shorter of their two times: the faster one's final PSNR, the slower
/// one's read off its training curve.
pub(super) fn equal_time(
    ctx: &Context,
    i: usize,
    views: usize,
    noise: &str,
    a: &str,
    b: &str,
) -> String {
    let st = &ctx.plan.studies[i];
    let seed = st.spec.seeds[0];
    let rows = ctx.study_rows(&st.spec.name);
    let mut md = format!(
        "Equal wall time (seed {seed}): both methods at the shorter of their two training times; the \
         slower method's PSNR is read off its training curve (`log.jsonl`), i.e. its configured \
         schedule stopped early, not a schedule planned for that budget.\n\n\
         | Scene | time | {la} PSNR | {lb} PSNR | Δ (dB) |\n|---|---:|---:|---:|---:|\n",
        la = label(ctx, a),
        lb = label(ctx, b)
    );
    for scene in &st.spec.scenes {
        let find = |m: &str| point(st, scene, m, views, noise, seed);
        let (Some(pa), Some(pb)) = (find(a), find(b)) else {
            continue;
        };
        let (Some(ra), Some(rb)) = (mean_row(&rows, pa), mean_row(&rows, pb)) else {
            continue;
        };
        let t = ra.wall_s.min(rb.wall_s);
        let at = |p: &StudyPoint, r: &Row| -> Option<f64> {
            if r.wall_s <= t {
                r.psnr
            } else {
                Curve::load(&ctx.plan.run_dir(ctx.out, p.run)).ok()?.at(t)
            }
        };
        let (xa, xb) = (at(pa, ra), at(pb, rb));
        let f = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.2}"));
        let d = match (xa, xb) {
            (Some(x), Some(y)) => format!("{:+.2}", x - y),
            _ => "–".into(),
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {d} |",
            ctx.loaded.suite.scene_label(scene),
            seconds(t),
            f(xa),
            f(xb)
        );
    }
    md.push('\n');
    md
}

/// Per method and scene, the training time at which its mean PSNR curve first reaches 95 % and
/// 99 % of its last value: "faster" stated at equal quality. Methods without a curve (the classic
/// ones) are left out; no table when none has one.
pub(super) fn time_to_quality(ctx: &Context, i: usize, views: usize, noise: &str) -> String {
    let st = &ctx.plan.studies[i];
    let seed = st.spec.seeds[0];
    let mut body = String::new();
    for method in &st.spec.methods {
        let cells: Vec<Option<Curve>> = st
            .spec
            .scenes
            .iter()
            .map(|scene| {
                let p = point(st, scene, method, views, noise, seed)?;
                Curve::load(&ctx.plan.run_dir(ctx.out, p.run))
                    .ok()
                    .filter(|c| !c.mean.is_empty())
            })
            .collect();
        if cells.iter().all(Option::is_none) {
            continue;
        }
        let mut line = format!("| {} |", label(ctx, method));
        for c in &cells {
            for q in [0.95, 0.99] {
                let t = c.as_ref().and_then(|c| c.time_to(q));
                let _ = write!(line, " {} |", t.map_or("–".into(), seconds));
            }
        }
        let _ = writeln!(body, "{line}");
    }
    if body.is_empty() {
        return String::new();
    }
    let mut md = format!(
        "Time to quality (seed {seed}): the training time at which each method's mean PSNR first \
         reaches 95 % and 99 % of its last evaluated value (in dB, linearly interpolated between \
         evaluations; per-channel methods as every channel stopped at the same iteration; 4D-SG's \
         curve starts with stage 2, so its times include all of stage 1). Each method against its \
         own last value: a method that stops improving early reaches it early.\n\n\
         | Method |"
    );
    let mut rule = String::from("|---|");
    for scene in &st.spec.scenes {
        let name = ctx.loaded.suite.scene_label(scene);
        let _ = write!(md, " {name} 95 % | 99 % |");
        rule.push_str("---:|---:|");
    }
    let _ = write!(md, "\n{rule}\n{body}\n");
    md
}

/// PSNR against training time, a panel per scene: Gaussian methods as curves (4D-SG's stage 1
/// dashed, scored against the mean reference), classic methods as points.
pub(super) fn psnr_time(ctx: &mut Context, i: usize, views: usize, noise: &str) -> Result<String> {
    let st = ctx.plan.studies[i].clone();
    let seed = st.spec.seeds[0];
    let rows = ctx.study_rows(&st.spec.name);
    let mut panels = Vec::new();
    for scene in &st.spec.scenes {
        let mut series = Vec::new();
        for p in st
            .points
            .iter()
            .filter(|p| &p.scene == scene && p.views == views && p.noise == noise && p.seed == seed)
        {
            let Some(r) = mean_row(&rows, p) else {
                continue;
            };
            let c = ctx.colour(&p.method);
            let name = label(ctx, &p.method);
            let curve = Curve::load(&ctx.plan.run_dir(ctx.out, p.run))?;
            if curve.mean.is_empty() {
                series.push(Series::points(
                    name,
                    c,
                    vec![(r.wall_s, r.psnr.unwrap_or(0.0))],
                ));
            } else {
                if !curve.structural.is_empty() {
                    series.push(Series {
                        dashed: true,
                        ..Series::line(format!("{name} stage 1 (mean ref.)"), c, curve.structural)
                    });
                }
                series.push(Series {
                    markers: true,
                    ..Series::line(name, c, curve.mean)
                });
            }
        }
        panels.push(Panel::psnr_time(
            ctx.loaded.suite.scene_label(scene),
            series,
        ));
    }
    let fig = Lines {
        title: format!("PSNR against training time, {views} views, noise {noise}, seed {seed}"),
        cols: panels.len().clamp(1, 3),
        panel: (440, 330),
        panels,
    };
    let paths = save(
        &ctx.figure_stem(&format!("{}-v{views}-{noise}-psnr-time", st.spec.name)),
        &fig,
    )?;
    Ok(ctx.embed(
        paths,
        &format!(
            "PSNR against training time ({views} views, noise {noise}); R²-Gaussian's curve stops \
             every channel at the same iteration"
        ),
    ))
}

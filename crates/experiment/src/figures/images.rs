//! Image grids: slice montages of every method and projection panels (reference, prediction,
//! residual). The images are composed pixel by pixel (nearest-neighbour upscaling, no smoothing,
//! so what is shown is what was reconstructed); the PNG gets its labels drawn by plotters, the SVG
//! embeds the same raster and carries the labels as text.

use super::plot::{SANS, font, msg, png_bytes, write_png};
use crate::{Error, Result};
use base64::Engine;
use ndarray::{Array2, ArrayView2};
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// How values become colours.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColourMap {
    /// Black at `lo`, white at `hi`, clamped.
    Grey { lo: f32, hi: f32 },
    /// Blue at −`max`, white at 0, red at +`max`, clamped (residuals).
    Diverging { max: f32 },
}

impl ColourMap {
    pub fn rgb(self, v: f32) -> [u8; 3] {
        if !v.is_finite() {
            return [255, 0, 255];
        }
        match self {
            ColourMap::Grey { lo, hi } => {
                let t = ((v - lo) / (hi - lo).max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
                let g = (t * 255.0).round() as u8;
                [g, g, g]
            }
            ColourMap::Diverging { max } => {
                let t = (v / max.max(f32::MIN_POSITIVE)).clamp(-1.0, 1.0);
                let (end, t) = if t < 0.0 {
                    ([33.0, 102.0, 172.0], -t)
                } else {
                    ([178.0, 24.0, 43.0], t)
                };
                let mix = |e: f32| (255.0 + (e - 255.0) * t).round() as u8;
                [mix(end[0]), mix(end[1]), mix(end[2])]
            }
        }
    }
}

/// One image of the grid, with its caption.
#[derive(Clone, Debug)]
pub struct Tile {
    pub caption: String,
    /// `[row][col]`, row 0 at the top.
    pub image: Array2<f32>,
    pub map: ColourMap,
}

/// Rows of tiles, each row with a label on its left.
#[derive(Clone, Debug)]
pub struct Grid {
    pub title: String,
    /// A line under the title (orientation, windows).
    pub note: String,
    /// `(label, tiles)`; a `None` tile leaves its place blank.
    pub rows: Vec<(String, Vec<Option<Tile>>)>,
    /// Integer upscaling of every image.
    pub scale: usize,
}

const TITLE_H: usize = 46;
const CAPTION_H: usize = 18;
const LABEL_W: usize = 120;
const GAP: usize = 8;

struct Text {
    x: usize,
    y: usize,
    size: u32,
    text: String,
}

impl Grid {
    fn cell(&self) -> (usize, usize) {
        let mut h = 1;
        let mut w = 1;
        for t in self.rows.iter().flat_map(|r| r.1.iter().flatten()) {
            h = h.max(t.image.nrows());
            w = w.max(t.image.ncols());
        }
        (w * self.scale, h * self.scale)
    }

    fn size(&self) -> (usize, usize) {
        let (cw, ch) = self.cell();
        let cols = self.rows.iter().map(|r| r.1.len()).max().unwrap_or(0);
        let text = self
            .title
            .chars()
            .count()
            .max(self.note.chars().count() * 7 / 10)
            * 10;
        (
            (LABEL_W + cols * (cw + GAP) + GAP).max(text + 20),
            TITLE_H + self.rows.len() * (ch + CAPTION_H + GAP) + GAP,
        )
    }

    /// The raster (white background, images placed) and the text to put on it.
    fn compose(&self) -> (Vec<u8>, usize, usize, Vec<Text>) {
        let (w, h) = self.size();
        let (cw, ch) = self.cell();
        let mut rgb = vec![255u8; w * h * 3];
        let mut texts = vec![
            Text {
                x: 10,
                y: 6,
                size: 18,
                text: self.title.clone(),
            },
            Text {
                x: 10,
                y: 28,
                size: 12,
                text: self.note.clone(),
            },
        ];
        for (r, (label, tiles)) in self.rows.iter().enumerate() {
            let y0 = TITLE_H + r * (ch + CAPTION_H + GAP);
            texts.push(Text {
                x: 8,
                y: y0 + CAPTION_H + ch / 2 - 7,
                size: 13,
                text: label.clone(),
            });
            for (c, t) in tiles.iter().enumerate() {
                let Some(t) = t else { continue };
                let x0 = LABEL_W + c * (cw + GAP);
                texts.push(Text {
                    x: x0,
                    y: y0 + 2,
                    size: 12,
                    text: t.caption.clone(),
                });
                blit(
                    &mut rgb,
                    w,
                    x0,
                    y0 + CAPTION_H,
                    t.image.view(),
                    t.map,
                    self.scale,
                );
            }
        }
        (rgb, w, h, texts)
    }

    /// Write `<stem>.png` and `<stem>.svg`.
    pub fn save(&self, stem: &Path) -> Result<[PathBuf; 2]> {
        let (rgb, w, h, texts) = self.compose();
        let png = stem.with_extension("png");
        let svg = stem.with_extension("svg");
        let fail = |p: &Path, m: String| Error::Figure {
            path: p.to_path_buf(),
            message: m,
        };
        // SVG: the raster without labels, the labels as text.
        let raster = png_bytes(&rgb, w as u32, h as u32).map_err(|m| fail(&svg, m))?;
        let mut s = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" \
             viewBox=\"0 0 {w} {h}\">\n<image x=\"0\" y=\"0\" width=\"{w}\" height=\"{h}\" \
             style=\"image-rendering:pixelated\" href=\"data:image/png;base64,{}\"/>\n",
            base64::engine::general_purpose::STANDARD.encode(&raster)
        );
        for t in &texts {
            let _ = writeln!(
                s,
                "<text x=\"{}\" y=\"{}\" font-family=\"DejaVu Sans, {SANS}\" font-size=\"{}\">{}</text>",
                t.x,
                t.y as f64 + t.size as f64 * 0.85,
                t.size,
                xml_escape(&t.text)
            );
        }
        s.push_str("</svg>\n");
        std::fs::write(&svg, s).map_err(|e| Error::io(&svg, e))?;
        // PNG: the labels drawn onto the raster.
        super::plot::register_font();
        let mut labelled = rgb;
        {
            let root =
                BitMapBackend::with_buffer(&mut labelled, (w as u32, h as u32)).into_drawing_area();
            for t in &texts {
                root.draw_text(&t.text, &font(t.size), (t.x as i32, t.y as i32))
                    .map_err(|e| fail(&png, msg(e)))?;
            }
            root.present().map_err(|e| fail(&png, msg(e)))?;
        }
        write_png(&png, &labelled, w as u32, h as u32)?;
        Ok([png, svg])
    }
}

fn blit(
    rgb: &mut [u8],
    width: usize,
    x0: usize,
    y0: usize,
    img: ArrayView2<f32>,
    map: ColourMap,
    scale: usize,
) {
    for ((r, c), &v) in img.indexed_iter() {
        let px = map.rgb(v);
        for dy in 0..scale {
            for dx in 0..scale {
                let (x, y) = (x0 + c * scale + dx, y0 + r * scale + dy);
                let o = (y * width + x) * 3;
                if o + 3 <= rgb.len() {
                    rgb[o..o + 3].copy_from_slice(&px);
                }
            }
        }
    }
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_maps_hit_their_ends_and_clamp() {
        let g = ColourMap::Grey { lo: 0.0, hi: 2.0 };
        assert_eq!(g.rgb(0.0), [0, 0, 0]);
        assert_eq!(g.rgb(1.0), [128, 128, 128]);
        assert_eq!(g.rgb(5.0), [255, 255, 255]);
        let d = ColourMap::Diverging { max: 1.0 };
        assert_eq!(d.rgb(0.0), [255, 255, 255]);
        assert_eq!(d.rgb(-3.0), [33, 102, 172]);
        assert_eq!(d.rgb(1.0), [178, 24, 43]);
        assert_eq!(
            g.rgb(f32::NAN),
            [255, 0, 255],
            "non-finite values stand out"
        );
    }

    #[test]
    fn a_grid_places_each_image_pixel_for_pixel() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = Array2::<f32>::zeros((4, 6));
        img[[1, 2]] = 1.0;
        let grid = Grid {
            title: "t".into(),
            note: "axial slice".into(),
            rows: vec![(
                "40keV".into(),
                vec![Some(Tile {
                    caption: "SART".into(),
                    image: img,
                    map: ColourMap::Grey { lo: 0.0, hi: 1.0 },
                })],
            )],
            scale: 2,
        };
        let (rgb, w, _, _) = grid.compose();
        let at = |x: usize, y: usize| &rgb[(y * w + x) * 3..(y * w + x) * 3 + 3];
        let (x0, y0) = (LABEL_W, TITLE_H + CAPTION_H);
        assert_eq!(
            at(x0 + 4, y0 + 2),
            [255, 255, 255],
            "the bright pixel, upscaled"
        );
        assert_eq!(at(x0 + 5, y0 + 3), [255, 255, 255]);
        assert_eq!(at(x0 + 6, y0 + 2), [0, 0, 0]);
        assert_eq!(at(x0, y0), [0, 0, 0]);
        let [png, svg] = grid.save(&dir.path().join("g")).unwrap();
        assert!(png.exists());
        let svg = std::fs::read_to_string(svg).unwrap();
        assert!(svg.contains("data:image/png;base64,") && svg.contains(">SART<"));
    }
}

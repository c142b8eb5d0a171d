//! Drawing a figure once for both outputs: [`save`] renders a [`Draw`] to an SVG string
//! (plotters' SVG backend) and to an RGB buffer (its bitmap backend) that [`write_png`] encodes.
//! Text uses DejaVu Sans, embedded (`assets/`, Bitstream Vera licence), so figures look the same
//! on every machine and need no system font.

use crate::{Error, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Once;

/// The embedded font (DejaVu Sans, `assets/LICENSE-DejaVu.txt`).
const FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
/// The family every figure's text uses.
pub const SANS: &str = "sans-serif";

static FONT_ONCE: Once = Once::new();

pub(crate) fn register_font() {
    FONT_ONCE.call_once(|| {
        // The font is part of the binary; a failure here is a build defect.
        if plotters::style::register_font(SANS, FontStyle::Normal, FONT).is_err() {
            panic!("the embedded DejaVu Sans is not a valid font");
        }
    });
}

/// A figure that can be drawn on any plotters backend.
pub trait Draw {
    /// Size in pixels (the SVG's user units).
    fn size(&self) -> (u32, u32);
    /// Draw on `root`; errors are messages.
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>;
}

/// Write `figure` to `<stem>.png` and `<stem>.svg`; returns both paths.
pub fn save(stem: &Path, figure: &impl Draw) -> Result<[PathBuf; 2]> {
    register_font();
    let (w, h) = figure.size();
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    let fail = |p: &Path, m: String| Error::Figure {
        path: p.to_path_buf(),
        message: m,
    };
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| fail(&svg, e.to_string()))?;
        figure.draw(&root).map_err(|m| fail(&svg, m))?;
        root.present().map_err(|e| fail(&svg, e.to_string()))?;
    }
    std::fs::write(&svg, text).map_err(|e| Error::io(&svg, e))?;
    let mut rgb = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| fail(&png, e.to_string()))?;
        figure.draw(&root).map_err(|m| fail(&png, m))?;
        root.present().map_err(|e| fail(&png, e.to_string()))?;
    }
    write_png(&png, &rgb, w, h)?;
    Ok([png, svg])
}

/// Encode an RGB8 buffer (`w·h·3` bytes, rows top to bottom) as a PNG file.
pub fn write_png(path: &Path, rgb: &[u8], w: u32, h: u32) -> Result<()> {
    std::fs::write(
        path,
        png_bytes(rgb, w, h).map_err(|m| Error::Figure {
            path: path.to_path_buf(),
            message: m,
        })?,
    )
    .map_err(|e| Error::io(path, e))
}

/// An RGB8 buffer as PNG bytes.
pub fn png_bytes(rgb: &[u8], w: u32, h: u32) -> Result<Vec<u8>, String> {
    encode_png(rgb, w, h, png::ColorType::Rgb)
}

/// An 8-bit buffer of `colour` samples (`w·h·samples` bytes, rows top to bottom) as PNG bytes.
pub fn encode_png(
    pixels: &[u8],
    w: u32,
    h: u32,
    colour: png::ColorType,
) -> Result<Vec<u8>, String> {
    if pixels.len() != (w as usize) * (h as usize) * colour.samples() {
        return Err(format!(
            "{} bytes for a {w}×{h} {colour:?} image",
            pixels.len()
        ));
    }
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(colour);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(|e| e.to_string())?;
        writer.write_image_data(pixels).map_err(|e| e.to_string())?;
    }
    Ok(out)
}

/// The colour of series `i` (a qualitative palette that stays distinguishable in print).
pub fn colour(i: usize) -> RGBColor {
    const P: [(u8, u8, u8); 10] = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ];
    let (r, g, b) = P[i % P.len()];
    RGBColor(r, g, b)
}

/// A text style of `size` pixels.
pub fn font(size: u32) -> TextStyle<'static> {
    (SANS, size).into_font().into()
}

/// `e` as a message (plotters' drawing errors are generic over the backend).
pub fn msg<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Square;
    impl Draw for Square {
        fn size(&self) -> (u32, u32) {
            (40, 30)
        }
        fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
            root.draw(&Rectangle::new([(10, 5), (20, 15)], RED.filled()))
                .map_err(msg)?;
            root.draw_text("R²", &font(12), (22, 5)).map_err(msg)
        }
    }

    #[test]
    fn a_figure_is_written_as_a_png_and_an_svg_with_the_same_content() {
        let dir = tempfile::tempdir().unwrap();
        let [png, svg] = save(&dir.path().join("sq"), &Square).unwrap();
        let svg = std::fs::read_to_string(svg).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("R²") && svg.contains("#FF0000"));
        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(png).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (40, 30));
        let px = |x: usize, y: usize| &buf[(y * 40 + x) * 3..(y * 40 + x) * 3 + 3];
        assert_eq!(px(15, 10), [255, 0, 0], "the rectangle");
        assert_eq!(px(2, 25), [255, 255, 255], "the background");
        // The text was rasterised with the embedded font: some pixels right of the square are dark.
        let dark = (22..40)
            .flat_map(|x| (3..20).map(move |y| (x, y)))
            .filter(|&(x, y)| px(x, y)[0] < 128)
            .count();
        assert!(dark > 5, "{dark} dark pixels");
    }
}

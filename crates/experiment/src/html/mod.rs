//! The browsable report: one HTML page that a browser opens from disk with no network. The
//! Markdown report's text, tables and figures are in the page itself ([`markdown`]: figures
//! embedded as data URLs); its slice viewer (scroll through z, switch channel and method, one
//! display window for every panel, a residual view against the reference, a linked cursor) runs
//! on the script and style embedded in the page and loads each scene's volumes, when first
//! shown, from a script in the folder beside the page, `<page stem>-data/` ([`slices`]).
//! Copy the page with that folder.

pub mod markdown;
pub mod runs;
pub mod slices;

pub use runs::write_runs_page;
pub use slices::{Score, Shown, ShownChannel, SliceSet};

use crate::{Error, Result};
use prism_domain::observe::Observer;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

const TEMPLATE: &str = include_str!("assets/page.html");
const STYLE: &str = include_str!("assets/style.css");
const VIEWER: &str = include_str!("assets/viewer.js");

/// What [`write_page`] wrote.
#[derive(Clone, Debug)]
pub struct Page {
    pub html: PathBuf,
    /// The folder of the viewer's set scripts.
    pub data: PathBuf,
    /// Bytes of the page and of the folder's set scripts.
    pub bytes: u64,
}

/// The folder beside `page` that holds its viewer's data: `<stem>-data`.
pub fn data_dir(page: &Path) -> PathBuf {
    let stem = page
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "report".into());
    page.with_file_name(format!("{stem}-data"))
}

/// Write `page` from the Markdown `markdown` (read from `source`, links relative to its folder)
/// and the viewer's `sets` (written to [`data_dir`]).
pub fn write_page(
    page: &Path,
    title: &str,
    markdown: &str,
    source: &Path,
    sets: &[SliceSet],
    observer: &dyn Observer,
) -> Result<Page> {
    let base = source.parent().unwrap_or(Path::new("."));
    let fragment = markdown::render(markdown, base, source)?;
    let data = data_dir(page);
    std::fs::create_dir_all(&data).map_err(|e| Error::io(&data, e))?;
    slices::clear(&data)?;
    let folder = data
        .file_name()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    let mut index = Vec::new();
    let mut bytes = 0u64;
    observer.phase("html: slice viewer", sets.len() as u64);
    for (i, set) in sets.iter().enumerate() {
        let script = slices::script(i, &set.encode()?)?;
        let file = data.join(slices::file_name(i));
        std::fs::write(&file, &script).map_err(|e| Error::io(&file, e))?;
        bytes += script.len() as u64;
        index.push(serde_json::json!({
            "title": set.title,
            "file": format!("{folder}/{}", slices::file_name(i)),
        }));
        observer.progress(i as u64 + 1, &set.title);
    }
    let mut contents = String::new();
    for h in fragment.headings.iter().filter(|h| h.level == 2) {
        let _ = writeln!(
            contents,
            "<li><a href=\"#{}\">{}</a></li>",
            h.id,
            escape(&h.text)
        );
    }
    if !sets.is_empty() {
        contents.push_str("<li><a href=\"#slice-viewer\">Slice viewer</a></li>\n");
    }
    let index = serde_json::to_string(&index)
        .map_err(|e| Error::invalid("html", e.to_string()))?
        .replace("</", "<\\/");
    let html = fill(
        TEMPLATE,
        &[
            ("title", &escape(title)),
            ("style", STYLE),
            ("contents", &contents),
            (
                "viewer_hidden",
                if sets.is_empty() { " hidden" } else { "" },
            ),
            ("sets", &index),
            ("viewer", VIEWER),
            ("body", &fragment.html),
        ],
    );
    std::fs::write(page, &html).map_err(|e| Error::io(page, e))?;
    bytes += html.len() as u64;
    Ok(Page {
        html: page.to_path_buf(),
        data,
        bytes,
    })
}

/// `template` with every `{{key}}` replaced by its value, in one pass (a value is never scanned).
fn fill(template: &str, values: &[(&str, &str)]) -> String {
    let mut out =
        String::with_capacity(template.len() + values.iter().map(|v| v.1.len()).sum::<usize>());
    let mut rest = template;
    while let Some(start) = rest.find("{{") {
        out.push_str(&rest[..start]);
        let after = &rest[start + 2..];
        match after.find("}}").and_then(|end| {
            let key = &after[..end];
            values
                .iter()
                .find(|(k, _)| *k == key)
                .map(|(_, v)| (end, *v))
        }) {
            Some((end, v)) => {
                out.push_str(v);
                rest = &after[end + 2..];
            }
            None => {
                out.push_str("{{");
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

/// `text` with `&`, `<`, `>` and `"` escaped.
pub fn escape(text: &str) -> String {
    let mut s = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => s.push_str("&amp;"),
            '<' => s.push_str("&lt;"),
            '>' => s.push_str("&gt;"),
            '"' => s.push_str("&quot;"),
            c => s.push(c),
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_template_is_filled_once_and_unknown_keys_stay() {
        let t = "<{{a}}|{{b}}|{{c}}>";
        assert_eq!(fill(t, &[("a", "{{b}}"), ("b", "x")]), "<{{b}}|x|{{c}}>");
        assert_eq!(escape("a<b & \"c\">"), "a&lt;b &amp; &quot;c&quot;&gt;");
        assert_eq!(
            data_dir(Path::new("out/report.html")),
            Path::new("out/report-data")
        );
    }
}

//! A Markdown report as an HTML fragment: text, tables and lists as CommonMark (with GitHub's
//! tables) renders them, every figure read from disk and embedded as a data URL (the page needs
//! no file beside it for them), and every heading given an anchor for the page's contents.

use crate::{Error, Result};
use base64::Engine;
use pulldown_cmark::{CowStr, Event, HeadingLevel, Options, Parser, Tag, TagEnd, html};
use std::collections::HashSet;
use std::path::Path;

/// A heading of the fragment: its level (1–6), anchor and text.
#[derive(Clone, Debug, PartialEq)]
pub struct Heading {
    pub level: u8,
    pub id: String,
    pub text: String,
}

/// The rendered report.
#[derive(Clone, Debug)]
pub struct Fragment {
    pub html: String,
    pub headings: Vec<Heading>,
}

/// Render `markdown` (whose relative links are relative to `base`); `source` names the Markdown
/// in errors. An image link must name a PNG, SVG or JPEG file that exists: it is embedded.
pub fn render(markdown: &str, base: &Path, source: &Path) -> Result<Fragment> {
    let options = Options::ENABLE_TABLES | Options::ENABLE_STRIKETHROUGH;
    let mut events: Vec<Event> = Parser::new_ext(markdown, options).collect();
    let mut headings = Vec::new();
    let mut taken = HashSet::new();
    for i in 0..events.len() {
        match &events[i] {
            Event::Start(Tag::Heading { level, .. }) => {
                let level = heading_level(*level);
                let text = heading_text(&events[i + 1..]);
                let id = unique(slug(&text), &mut taken);
                if let Event::Start(Tag::Heading { id: slot, .. }) = &mut events[i] {
                    *slot = Some(CowStr::from(id.clone()));
                }
                headings.push(Heading { level, id, text });
            }
            Event::Start(Tag::Image { dest_url, .. }) => {
                let url = embed(base, dest_url, source)?;
                if let Event::Start(Tag::Image { dest_url, .. }) = &mut events[i] {
                    *dest_url = CowStr::from(url);
                }
            }
            _ => {}
        }
    }
    let mut out = String::with_capacity(markdown.len() * 2);
    html::push_html(&mut out, events.into_iter());
    Ok(Fragment {
        html: out,
        headings,
    })
}

fn heading_level(l: HeadingLevel) -> u8 {
    match l {
        HeadingLevel::H1 => 1,
        HeadingLevel::H2 => 2,
        HeadingLevel::H3 => 3,
        HeadingLevel::H4 => 4,
        HeadingLevel::H5 => 5,
        HeadingLevel::H6 => 6,
    }
}

/// The plain text of the heading that starts before `rest`.
fn heading_text(rest: &[Event]) -> String {
    let mut text = String::new();
    for e in rest {
        match e {
            Event::End(TagEnd::Heading(_)) => break,
            Event::Text(t) | Event::Code(t) => text.push_str(t),
            _ => {}
        }
    }
    text
}

/// Lower-case letters and digits of `text`, runs of anything else as one `-`.
fn slug(text: &str) -> String {
    let mut s = String::new();
    for c in text.chars().flat_map(char::to_lowercase) {
        if c.is_alphanumeric() {
            s.push(c);
        } else if !s.ends_with('-') && !s.is_empty() {
            s.push('-');
        }
    }
    let s = s.trim_end_matches('-').to_string();
    if s.is_empty() { "section".into() } else { s }
}

fn unique(id: String, taken: &mut HashSet<String>) -> String {
    let mut candidate = id.clone();
    let mut n = 2;
    while !taken.insert(candidate.clone()) {
        candidate = format!("{id}-{n}");
        n += 1;
    }
    candidate
}

/// The image `url` (relative to `base`) as a data URL; absolute and data URLs are refused or kept.
fn embed(base: &Path, url: &str, source: &Path) -> Result<String> {
    if url.starts_with("data:") {
        return Ok(url.to_string());
    }
    let mime = match Path::new(url).extension().and_then(|e| e.to_str()) {
        Some("png") => "image/png",
        Some("svg") => "image/svg+xml",
        Some("jpg" | "jpeg") => "image/jpeg",
        _ => {
            return Err(Error::field(
                source,
                url,
                "an embedded image must be a .png, .svg or .jpg file",
            ));
        }
    };
    let path = base.join(url);
    let bytes = std::fs::read(&path).map_err(|e| {
        Error::field(
            source,
            url,
            format!("the figure {} cannot be read: {e}", path.display()),
        )
    })?;
    Ok(data_url(mime, &bytes))
}

/// `bytes` as a `data:` URL of type `mime`.
pub fn data_url(mime: &str, bytes: &[u8]) -> String {
    format!(
        "data:{mime};base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_headings_and_figures_render_with_figures_embedded() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("figures")).unwrap();
        std::fs::write(dir.path().join("figures/a.png"), [0x89, b'P', b'N', b'G']).unwrap();
        let md = "# Suite `cpu`\n\n## Study `table` (table)\n\n| Method | PSNR |\n|---|---:|\n| FDK | **20.1** |\n\n\
                  ![chart](figures/a.png)\n\n## Study `table` (table)\n";
        let f = render(md, dir.path(), &dir.path().join("report.md")).unwrap();
        assert!(f.html.contains("<table>") && f.html.contains("<strong>20.1</strong>"));
        assert!(f.html.contains("<td style=\"text-align: right\">"));
        assert!(f.html.contains("src=\"data:image/png;base64,iVBORw==\""));
        let ids: Vec<&str> = f.headings.iter().map(|h| h.id.as_str()).collect();
        assert_eq!(
            ids,
            ["suite-cpu", "study-table-table", "study-table-table-2"]
        );
        assert!(f.html.contains("<h2 id=\"study-table-table-2\">"));
        assert_eq!(f.headings[0].text, "Suite cpu");
    }

    #[test]
    fn a_missing_figure_names_the_report_and_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let e = render(
            "![x](figures/gone.png)\n",
            dir.path(),
            Path::new("report.md"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("gone.png") && e.contains("report.md"), "{e}");
    }
}

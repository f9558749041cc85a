//! Writing evaluation reports: files with their path in every error, Markdown tables, and the
//! precision–recall figure (the paper's Fig. 14) as PNG and SVG with `plotters`.
//!
//! Text in the PNG is drawn with `ab_glyph` from the DejaVu Sans font the `dejavu` crate
//! embeds, so plots render the same on a bare machine with no system fonts.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;

use super::metrics::RECALL_LEVELS;
use salient_core::{Error, Result};

/// Writes `contents` to `path`, creating its folder.
pub fn write(path: &Path, contents: impl AsRef<[u8]>) -> Result<()> {
    let failed = |e: std::io::Error| Error::Report {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(failed)?;
    }
    std::fs::write(path, contents).map_err(failed)
}

/// Writes `value` as pretty JSON.
pub fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::Report {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    write(path, text + "\n")
}

/// A Markdown table.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    pub fn new<S: ToString>(header: impl IntoIterator<Item = S>) -> Self {
        Self {
            header: header.into_iter().map(|s| s.to_string()).collect(),
            rows: Vec::new(),
        }
    }

    pub fn row<S: ToString>(&mut self, cells: impl IntoIterator<Item = S>) {
        self.rows
            .push(cells.into_iter().map(|s| s.to_string()).collect());
    }

    /// The table, first column left-aligned and the others right-aligned (numbers).
    pub fn markdown(&self) -> String {
        let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
        let rule: Vec<String> = (0..self.header.len())
            .map(|i| if i == 0 { "---" } else { "---:" }.to_string())
            .collect();
        let mut text = line(&self.header) + &line(&rule);
        for row in &self.rows {
            text += &line(row);
        }
        text
    }
}

/// A score with three decimals.
pub fn score(x: f64) -> String {
    format!("{x:.3}")
}

/// Writes the 11-point precision–recall curves, one per method, to `png` and `svg`.
pub fn precision_recall_plot(
    title: &str,
    curves: &[(&str, [f64; RECALL_LEVELS])],
    png: &Path,
    svg: &Path,
) -> Result<()> {
    static FONT: Once = Once::new();
    FONT.call_once(|| {
        // The embedded font is a valid TrueType file; registering cannot fail.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
    let failed = |path: &Path, e: String| Error::Report {
        path: path.to_path_buf(),
        message: e,
    };
    for path in [png, svg] {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| failed(path, e.to_string()))?;
        }
    }
    const SIZE: (u32, u32) = (720, 540);
    draw(
        BitMapBackend::new(png, SIZE).into_drawing_area(),
        title,
        curves,
    )
    .map_err(|e| failed(png, e))?;
    draw(
        SVGBackend::new(svg, SIZE).into_drawing_area(),
        title,
        curves,
    )
    .map_err(|e| failed(svg, e))
}

/// Distinct colours for up to six curves, then repeating.
const COLOURS: [RGBColor; 6] = [
    RGBColor(214, 39, 40),
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    curves: &[(&str, [f64; RECALL_LEVELS])],
) -> std::result::Result<(), String> {
    let error = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(error)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(56)
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)
        .map_err(error)?;
    chart
        .configure_mesh()
        .x_desc("Recall")
        .y_desc("Precision")
        .x_labels(11)
        .y_labels(11)
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .max_light_lines(0)
        .draw()
        .map_err(error)?;
    for (i, (name, pr)) in curves.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let points = pr
            .iter()
            .enumerate()
            .map(|(level, &p)| (level as f64 / (RECALL_LEVELS - 1) as f64, p));
        chart
            .draw_series(LineSeries::new(points, colour.stroke_width(2)).point_size(3))
            .map_err(error)?
            .label(*name)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font(("sans-serif", 15))
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()
        .map_err(error)?;
    root.present().map_err(error)
}

//! PNG charts for people who would rather look than read: loss curves, residual traces,
//! paths, scatter clouds and bar charts. Pure Rust (the font is embedded), so it works on
//! a bare CI machine.

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // invariant: the embedded font is loaded by every plot test.
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .unwrap_or_else(|_| panic!("embedded DejaVuSans.ttf is a valid font"));
    });
}

/// A chart that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[error("plot {file}: {message}")]
pub struct PlotError {
    /// The PNG's path.
    pub file: String,
    /// What went wrong.
    pub message: String,
}

impl crate::error::StageError for PlotError {}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Style {
    /// A polyline through the points, in order.
    #[default]
    Line,
    /// One small translucent dot per point (a scatter cloud).
    Points,
    /// One bar per point, from y = 0 to y, [`BAR_WIDTH`] x-units wide and centred on x
    /// (put the bars at x = 0, 1, 2, …). In a panel made only of bars, the x-axis is
    /// labelled at each bar with the name of its series instead of numbers, and there is
    /// no legend.
    Bars,
}

/// Width of a [`Style::Bars`] bar in x-units.
pub const BAR_WIDTH: f64 = 0.8;

/// One series of a chart: a line (the default), a scatter cloud or bars.
#[derive(Clone, Debug)]
pub struct Series {
    /// The legend's label (and a bar's x-axis label).
    pub name: String,
    /// `(x, y)` in the axes' units.
    pub points: Vec<(f64, f64)>,
    /// How it is drawn.
    pub style: Style,
}

impl Series {
    /// A line through `points`.
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            name: name.into(),
            points,
            style: Style::Line,
        }
    }

    /// A scatter cloud of `points`.
    pub fn scatter(name: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            style: Style::Points,
            ..Series::new(name, points)
        }
    }

    /// Bars at `points` (x = position of the bar's centre, y = its height).
    pub fn bars(name: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            style: Style::Bars,
            ..Series::new(name, points)
        }
    }

    /// The x values the chart must show: bars take their width, the rest their points.
    fn x_extent(&self) -> Vec<f64> {
        match self.style {
            Style::Bars => self
                .points
                .iter()
                .flat_map(|p| [p.0 - 0.5 * BAR_WIDTH, p.0 + 0.5 * BAR_WIDTH])
                .collect(),
            _ => self.points.iter().map(|p| p.0).collect(),
        }
    }

    /// The y values the chart must show: bars also need their base at 0.
    fn y_extent(&self) -> Vec<f64> {
        let mut ys: Vec<f64> = self.points.iter().map(|p| p.1).collect();
        if self.style == Style::Bars && !ys.is_empty() {
            ys.push(0.0);
        }
        ys
    }
}

/// One chart: a title, axis labels and its lines.
#[derive(Clone, Debug, Default)]
pub struct Panel {
    /// The chart's title.
    pub title: String,
    /// The x axis's label, with its unit.
    pub x_label: String,
    /// The y axis's label, with its unit.
    pub y_label: String,
    /// The series drawn, in legend order.
    pub series: Vec<Series>,
    /// Same scale on both axes (for paths in a plane).
    pub equal_aspect: bool,
    /// The x axis on a log scale (ticks labelled with the values); points with x ≤ 0
    /// are left out.
    pub log_x: bool,
    /// The x axis counts whole things (iterations): ticks only at integers.
    pub integer_x: bool,
}

impl Panel {
    /// The panel with every x replaced by its log10, for a linear chart whose ticks are
    /// labelled 10^x.
    fn with_log10_x(&self) -> Panel {
        let mut p = self.clone();
        for s in &mut p.series {
            s.points.retain(|pt| pt.0 > 0.0);
            for pt in &mut s.points {
                pt.0 = pt.0.log10();
            }
        }
        p
    }
}

/// A tick label of an axis of whole numbers: the integer, or nothing between two.
fn integer_tick(v: &f64) -> String {
    if (v - v.round()).abs() < 1e-9 {
        format!("{}", v.round())
    } else {
        String::new()
    }
}

/// A tick label of a log axis at log10 value `v`: the value, with two significant
/// decimals below 10.
fn log_tick(v: &f64) -> String {
    let x = 10f64.powf(*v);
    if x >= 10.0 {
        format!("{x:.0}")
    } else {
        format!("{x:.2}")
    }
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v), b.max(v)));
    if lo > hi {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-9 * hi.abs().max(1.0));
    (lo - pad, hi + pad)
}

/// Draws `panels` on a grid of `rows × cols` into a PNG of `size` pixels, written
/// atomically (temporary file, then rename).
pub fn draw(
    path: &Path,
    panels: &[Panel],
    rows: usize,
    cols: usize,
    size: (u32, u32),
) -> Result<(), PlotError> {
    render(path, size, |root, err| {
        let areas = root.split_evenly((rows, cols));
        for (panel, area) in panels.iter().zip(areas.iter()) {
            let logged;
            let panel = if panel.log_x {
                logged = panel.with_log10_x();
                &logged
            } else {
                panel
            };
            let (mut x0, mut x1) = range(panel.series.iter().flat_map(Series::x_extent));
            let (mut y0, mut y1) = range(panel.series.iter().flat_map(Series::y_extent));
            if panel.equal_aspect {
                let (w, h) = area.dim_in_pixel();
                let (sx, sy) = ((x1 - x0) / w as f64, (y1 - y0) / h as f64);
                let s = sx.max(sy);
                let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
                (x0, x1) = (cx - 0.5 * s * w as f64, cx + 0.5 * s * w as f64);
                (y0, y1) = (cy - 0.5 * s * h as f64, cy + 0.5 * s * h as f64);
            }
            let mut chart = ChartBuilder::on(area)
                .caption(&panel.title, ("sans-serif", 18))
                .margin(10)
                .x_label_area_size(35)
                .y_label_area_size(60)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(|e| err(&e))?;
            // A panel of bars only is categorical: name each bar on the x-axis.
            let bars: Vec<(f64, &str)> = panel
                .series
                .iter()
                .filter(|s| s.style == Style::Bars)
                .flat_map(|s| s.points.iter().map(move |p| (p.0, s.name.as_str())))
                .collect();
            let categorical =
                !bars.is_empty() && panel.series.iter().all(|s| s.style == Style::Bars);
            let bar_label = |v: &f64| -> String {
                bars.iter()
                    .find(|b| (b.0 - v).abs() < 1e-6)
                    .map_or(String::new(), |b| b.1.to_string())
            };
            let mut mesh = chart.configure_mesh();
            mesh.x_desc(&panel.x_label)
                .y_desc(&panel.y_label)
                .label_style(("sans-serif", 12));
            if panel.log_x {
                mesh.x_label_formatter(&log_tick);
            }
            if panel.integer_x && !panel.log_x {
                // One tick per whole number in range (at most 20), none between.
                let whole = (x1.floor() - x0.ceil()).max(0.0) as usize + 1;
                mesh.x_labels(whole.min(20))
                    .x_label_formatter(&integer_tick);
            }
            if categorical {
                // A label at every whole x in range, so that every bar gets its name.
                mesh.x_labels((x1 - x0).ceil() as usize + 2)
                    .x_label_formatter(&bar_label)
                    .disable_x_mesh();
            }
            mesh.draw().map_err(|e| err(&e))?;
            for (i, s) in panel.series.iter().enumerate() {
                let color = Palette99::pick(i).to_rgba();
                let finite = s
                    .points
                    .iter()
                    .copied()
                    .filter(|p| p.0.is_finite() && p.1.is_finite());
                let anno = match s.style {
                    Style::Line => chart
                        .draw_series(LineSeries::new(
                            s.points.iter().copied(),
                            color.stroke_width(1),
                        ))
                        .map_err(|e| err(&e))?
                        .legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                        }),
                    Style::Points => chart
                        .draw_series(finite.map(|p| Circle::new(p, 2, color.mix(0.45).filled())))
                        .map_err(|e| err(&e))?
                        .legend(move |(x, y)| Circle::new((x + 8, y), 3, color.filled())),
                    Style::Bars => chart
                        .draw_series(finite.map(|(x, y)| {
                            Rectangle::new(
                                [(x - 0.5 * BAR_WIDTH, 0.0), (x + 0.5 * BAR_WIDTH, y)],
                                color.mix(0.85).filled(),
                            )
                        }))
                        .map_err(|e| err(&e))?
                        .legend(move |(x, y)| {
                            Rectangle::new([(x + 2, y - 5), (x + 14, y + 5)], color.filled())
                        }),
                };
                anno.label(&s.name);
            }
            // A categorical panel names its bars on the x-axis; a legend would only cover them.
            if panel.series.len() > 1 && !categorical {
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 12))
                    .draw()
                    .map_err(|e| err(&e))?;
            }
        }
        Ok(())
    })
}

/// Draws into a white PNG of `size` pixels at `path`, written atomically: `body` draws
/// on the root area (its errors made with `err`) of an RGB buffer, which is encoded as a
/// PNG (the `png` crate: plotters' own encoder would compile a whole image library) and
/// written with [`crate::atomic::write`] (a full disk fails it and leaves `path` as it
/// was).
fn render(
    path: &Path,
    size: (u32, u32),
    body: impl FnOnce(
        &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
        &dyn Fn(&dyn std::fmt::Display) -> PlotError,
    ) -> Result<(), PlotError>,
) -> Result<(), PlotError> {
    register_font();
    let file = path.display().to_string();
    let err = |e: &dyn std::fmt::Display| PlotError {
        file: file.clone(),
        message: e.to_string(),
    };
    let mut pixels = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        body(&root, &err)?;
        root.present().map_err(|e| err(&e))?;
    }
    let mut encoded = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut encoded, size.0, size.1);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
        let mut writer = encoder.write_header().map_err(|e| err(&e))?;
        writer.write_image_data(&pixels).map_err(|e| err(&e))?;
        writer.finish().map_err(|e| err(&e))?;
    }
    crate::atomic::write(path, &encoded).map_err(|e| err(&e))
}

/// One square map for [`heat_maps`]: a title and `n × n` values, row-major, row 0 at the
/// bottom; `NaN` pixels (off the part) are left white.
#[derive(Clone, Debug)]
pub struct HeatMap {
    /// The panel's title: up to [`HEAT_TITLE_LINES`] lines (split at `\n`), each drawn
    /// within its panel.
    pub title: String,
    /// Pixels per side.
    pub n: usize,
    /// The values, row-major.
    pub values: Vec<f64>,
}

/// Lines of a [`HeatMap`]'s title that have room above its map.
pub const HEAT_TITLE_LINES: usize = 2;

/// Blue (low) through white to red (high), for `t` in [0, 1].
fn diverging(t: f64) -> RGBColor {
    let t = t.clamp(0.0, 1.0);
    let (lo, mid, hi) = (
        (49.0, 54.0, 149.0),
        (247.0, 247.0, 247.0),
        (165.0, 0.0, 38.0),
    );
    let (a, b, f) = if t < 0.5 {
        (lo, mid, 2.0 * t)
    } else {
        (mid, hi, 2.0 * t - 1.0)
    };
    let mix = |x: f64, y: f64| (x + f * (y - x)).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Draws `maps` on a grid of `cols` columns into a PNG, every panel on the one colour
/// scale `range` (`unit` names it in the caption), written atomically.
pub fn heat_maps(
    path: &Path,
    maps: &[HeatMap],
    cols: usize,
    range: (f64, f64),
    unit: &str,
) -> Result<(), PlotError> {
    let cols = cols.max(1);
    let rows = maps.len().div_ceil(cols).max(1);
    let cell = 320u32;
    let title_px = 18 * HEAT_TITLE_LINES as u32 + 8;
    let size = (cols as u32 * cell, rows as u32 * (cell + title_px) + 40);
    render(path, size, |root, err| {
        let (legend, body) = root.split_vertically(40);
        legend
            .draw(&Text::new(
                format!(
                    "colour scale {:.1} (blue) to {:.1} (red) {unit}, shared by every panel",
                    range.0, range.1
                ),
                (10, 12),
                ("sans-serif", 16),
            ))
            .map_err(|e| err(&e))?;
        let span = (range.1 - range.0).max(1e-12);
        for (map, area) in maps.iter().zip(body.split_evenly((rows, cols)).iter()) {
            let (title, plot) = area.split_vertically(title_px);
            for (k, line) in map.title.lines().take(HEAT_TITLE_LINES).enumerate() {
                title
                    .draw(&Text::new(
                        line.to_string(),
                        (8, 6 + 18 * k as i32),
                        ("sans-serif", 14),
                    ))
                    .map_err(|e| err(&e))?;
            }
            let (w, h) = plot.dim_in_pixel();
            let side = w.min(h) as usize;
            let n = map.n.max(1);
            for py in 0..side {
                for px in 0..side {
                    let c = px * n / side;
                    let r = n - 1 - py * n / side;
                    let v = map.values[r * n + c];
                    if v.is_finite() {
                        plot.draw_pixel((px as i32, py as i32), &diverging((v - range.0) / span))
                            .map_err(|e| err(&e))?;
                    }
                }
            }
        }
        Ok(())
    })
}

/// One panel of [`cell_maps`]: a title and one value per cell, row-major, row 0 at the
/// bottom (`NaN`: no value).
#[derive(Clone, Debug)]
pub struct CellMap {
    /// The panel's title.
    pub title: String,
    /// `rows × cols` values.
    pub values: Vec<f64>,
}

/// The axes every panel of [`cell_maps`] shares: a label per column and per row, and
/// marks drawn as vertical lines at fractional column positions (0 at the first
/// column's centre), each with a letter, named in the figure's caption.
#[derive(Clone, Debug)]
pub struct CellAxes {
    /// The columns' labels, left to right.
    pub columns: Vec<String>,
    /// The rows' labels, bottom to top.
    pub rows: Vec<String>,
    /// What the columns are.
    pub x_title: String,
    /// What the rows are.
    pub y_title: String,
    /// `(column position, name)`.
    pub marks: Vec<(f64, String)>,
}

/// White (at `range.0` and below) to red (at `range.1`) on a log scale, for the value `v`.
fn sequential_log(v: f64, range: (f64, f64)) -> RGBColor {
    if v.is_nan() || v <= range.0 {
        return diverging(0.5);
    }
    let (lo, hi) = (range.0.log10(), range.1.log10());
    diverging(0.5 + 0.5 * (v.log10() - lo) / (hi - lo).max(1e-12))
}

/// Draws `maps` on a grid of `cols` panels per row into a PNG of cells, each coloured by
/// its value on a log scale from `range.0` (white; that and below) to `range.1` (red),
/// labelled with it (`unit` names it) and outlined where it is at least `outline`, the
/// marks of `axes` over every panel; written atomically.
pub fn cell_maps(
    path: &Path,
    maps: &[CellMap],
    cols: usize,
    axes: &CellAxes,
    range: (f64, f64),
    outline: f64,
    unit: &str,
) -> Result<(), PlotError> {
    let cols = cols.max(1);
    let rows = maps.len().div_ceil(cols).max(1);
    let (nx, ny) = (axes.columns.len().max(1), axes.rows.len().max(1));
    let letter = |k: usize| char::from(b'a' + (k % 26) as u8);
    let caption = 24 * (1 + axes.marks.len().div_ceil(2)) as u32;
    // A panel's height follows its rows: 45 px each beside the title and the axes.
    let panel = (140 + 45 * ny as u32).min(400);
    let size = (cols as u32 * 520, rows as u32 * panel + caption);
    render(path, size, |root, err| {
        let (legend, body) = root.split_vertically(caption);
        let mut lines = vec![format!(
            "each cell: {unit}; colour from {} (white, and below) to {:.1} (red) on a log scale; outlined: {outline} or more",
            range.0, range.1
        )];
        for (k, chunk) in axes.marks.chunks(2).enumerate() {
            lines.push(
                chunk
                    .iter()
                    .enumerate()
                    .map(|(j, (_, name))| format!("{}: {name}", letter(2 * k + j)))
                    .collect::<Vec<_>>()
                    .join("    "),
            );
        }
        for (k, line) in lines.iter().enumerate() {
            legend
                .draw(&Text::new(
                    line.clone(),
                    (10, 6 + 22 * k as i32),
                    ("sans-serif", 15),
                ))
                .map_err(|e| err(&e))?;
        }
        // The label of the column or row whose centre is at `v`, none between.
        let label = |labels: &[String], v: f64| -> String {
            let i = v.round();
            match labels.get(i as usize) {
                Some(l) if (v - i).abs() < 1e-6 && i >= 0.0 => l.clone(),
                _ => String::new(),
            }
        };
        let column = |v: &f64| label(&axes.columns, *v);
        let row = |v: &f64| label(&axes.rows, *v);
        for (map, area) in maps.iter().zip(body.split_evenly((rows, cols)).iter()) {
            let mut chart = ChartBuilder::on(area)
                .caption(&map.title, ("sans-serif", 16))
                .margin(10)
                .x_label_area_size(40)
                .y_label_area_size(55)
                .build_cartesian_2d(-0.5..nx as f64 - 0.5, -0.5..ny as f64 - 0.5)
                .map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_labels(nx)
                .y_labels(ny)
                .x_label_formatter(&column)
                .y_label_formatter(&row)
                .x_desc(&axes.x_title)
                .y_desc(&axes.y_title)
                .label_style(("sans-serif", 12))
                .draw()
                .map_err(|e| err(&e))?;
            // Every cell's centre and value (NaN where the map has none).
            let cells = (0..ny).flat_map(|r| {
                (0..nx).map(move |c| {
                    let v = map.values.get(r * nx + c).copied().unwrap_or(f64::NAN);
                    (c as f64, r as f64, v)
                })
            });
            chart
                .draw_series(cells.clone().map(|(x, y, v)| {
                    Rectangle::new(
                        [(x - 0.5, y - 0.5), (x + 0.5, y + 0.5)],
                        sequential_log(v, range).filled(),
                    )
                }))
                .map_err(|e| err(&e))?;
            chart
                .draw_series(cells.clone().filter(|c| c.2 >= outline).map(|(x, y, _)| {
                    Rectangle::new(
                        [(x - 0.47, y - 0.47), (x + 0.47, y + 0.47)],
                        BLACK.stroke_width(2),
                    )
                }))
                .map_err(|e| err(&e))?;
            let style = TextStyle::from(("sans-serif", 12).into_font())
                .pos(Pos::new(HPos::Center, VPos::Center));
            // White figures on the darker reds.
            let dark = range.1.log10() - 0.4 * (range.1.log10() - range.0.log10());
            chart
                .draw_series(cells.map(|(x, y, v)| {
                    let text = if v.is_finite() {
                        format!("{v:.2}")
                    } else {
                        String::new()
                    };
                    let style = if v > 0.0 && v.log10() > dark {
                        style.color(&WHITE)
                    } else {
                        style.clone()
                    };
                    Text::new(text, (x, y), style)
                }))
                .map_err(|e| err(&e))?;
            for (k, (x, _)) in axes.marks.iter().enumerate() {
                chart
                    .draw_series(DashedLineSeries::new(
                        [(*x, -0.5), (*x, ny as f64 - 0.5)],
                        6,
                        4,
                        BLUE.stroke_width(1),
                    ))
                    .map_err(|e| err(&e))?;
                let top = ny as f64 - 0.5 - 0.3 * (1 + k % 3) as f64;
                chart
                    .draw_series(std::iter::once(Text::new(
                        letter(k).to_string(),
                        (*x + 0.06, top),
                        ("sans-serif", 15).into_font().color(&BLUE),
                    )))
                    .map_err(|e| err(&e))?;
            }
        }
        Ok(())
    })
}

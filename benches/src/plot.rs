//! Line plots of an error against a knob (log-scale error), for the experiments' PNG figures.

use std::path::Path;

/// One point of a line plot: the series it belongs to, its x and its (positive) y.
pub type PlotPoint = (String, f64, f64);

/// What a plot's axes and title say, and how x tick values are printed.
pub struct PlotLabels<'a> {
    /// The caption above the plot.
    pub title: &'a str,
    /// The x axis' description.
    pub x: &'a str,
    /// The y axis' description (the axis is log-scale).
    pub y: &'a str,
    /// Prints an x tick value (e.g. `10^v` when x holds a base-10 logarithm).
    pub x_ticks: &'a dyn Fn(f64) -> String,
}

/// Draws `points` as one line per series (in order of first appearance, points sorted by x),
/// y on a log scale (non-positive y is left out), into a 760 × 480 PNG at `path`.
pub fn plot_lines(
    points: &[PlotPoint],
    labels: &PlotLabels<'_>,
    path: &Path,
) -> Result<(), String> {
    use plotters::prelude::*;
    let failed = |e: &dyn std::fmt::Display| format!("plot {}: {e}", path.display());
    plotters::style::register_font(
        "sans-serif",
        FontStyle::Normal,
        epaint_default_fonts::UBUNTU_LIGHT,
    )
    .map_err(|_| failed(&"cannot register the font"))?;
    let shown = || points.iter().filter(|p| p.2 > 0.0);
    let xs = shown().map(|p| p.1);
    let (x0, x1) = (
        xs.clone().fold(f64::MAX, f64::min),
        xs.fold(f64::MIN, f64::max),
    );
    let ys = shown().map(|p| p.2);
    let lo = ys.clone().fold(f64::MAX, f64::min) * 0.5;
    let hi = ys.fold(f64::MIN, f64::max) * 2.0;
    if shown().next().is_none() {
        return Err(failed(&"no positive value to plot"));
    }
    let root = BitMapBackend::new(path, (760, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| failed(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(labels.title, ("sans-serif", 20))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(80)
        .build_cartesian_2d(x0..x1.max(x0 + 1.0), (lo..hi).log_scale())
        .map_err(|e| failed(&e))?;
    chart
        .configure_mesh()
        .x_desc(labels.x)
        .y_desc(labels.y)
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .x_label_formatter(&|v| (labels.x_ticks)(*v))
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|e| failed(&e))?;
    let mut series: Vec<&str> = Vec::new();
    for p in points {
        if !series.contains(&p.0.as_str()) {
            series.push(&p.0);
        }
    }
    for (i, name) in series.iter().enumerate() {
        let colour = Palette99::pick(i).stroke_width(2);
        let mut line: Vec<(f64, f64)> = shown()
            .filter(|p| p.0 == *name)
            .map(|p| (p.1, p.2))
            .collect();
        line.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(line.clone(), colour))
            .map_err(|e| failed(&e))?
            .label(*name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], colour));
        chart
            .draw_series(line.into_iter().map(|p| Circle::new(p, 3, colour.filled())))
            .map_err(|e| failed(&e))?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(|e| failed(&e))?;
    root.present().map_err(|e| failed(&e))
}

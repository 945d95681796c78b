//! Line plots as inline SVG text: one or more series on shared axes with round-number ticks, a
//! legend, and a dot on each measured point when there are few. Used by the HTML report and by
//! `svgir bench train`'s convergence curve; builds a string, writes nothing.

use std::fmt::Write as _;

/// One curve: a name for the legend and its `(x, y)` points in drawing order.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text (empty: no legend entry).
    pub name: String,
    /// Points, in the order they are joined.
    pub points: Vec<(f64, f64)>,
}

/// Colours of successive series (colour-blind-safe Okabe-Ito hues).
const COLOURS: [&str; 6] = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9"];

/// About five round tick values covering `[lo, hi]` (steps of 1, 2 or 5 times a power of ten).
pub fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let raw = (hi - lo) / 5.0;
    let mag = 10f64.powf(raw.log10().floor());
    // The round step nearest a fifth of the range (from below within 25%): 4 to 7 ticks.
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| *s >= 0.75 * raw).unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Formats a tick value with as many decimals as its step needs.
fn tick_label(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 { 0 } else { (-step.log10().floor()) as usize };
    format!("{v:.decimals$}")
}

/// An SVG line plot of `series` (`width` x `height` user units, scaling to its container).
/// Returns an empty string when no series has two points.
pub fn line_plot(series: &[Series], title: &str, xlabel: &str, ylabel: &str, width: f64, height: f64) -> String {
    let drawn: Vec<&Series> = series.iter().filter(|s| s.points.len() >= 2).collect();
    if drawn.is_empty() {
        return String::new();
    }
    let all = drawn.iter().flat_map(|s| s.points.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in all {
        (x0, x1, y0, y1) = (x0.min(p.0), x1.max(p.0), y0.min(p.1), y1.max(p.1));
    }
    if y1 - y0 < 1e-9 {
        (y0, y1) = (y0 - 0.5, y1 + 0.5);
    }
    let (left, right, top, bottom) = (52.0, 12.0, 28.0, 40.0);
    let sx = |x: f64| left + (x - x0) / (x1 - x0).max(1e-12) * (width - left - right);
    let sy = |y: f64| height - bottom - (y - y0) / (y1 - y0) * (height - top - bottom);
    let mut s = format!(
        "<svg viewBox=\"0 0 {width} {height}\" width=\"{width}\" class=\"plot\" xmlns=\"http://www.w3.org/2000/svg\" \
font-family=\"sans-serif\" font-size=\"11\"><rect width=\"{width}\" height=\"{height}\" fill=\"white\"/>\
<text x=\"{left}\" y=\"16\" font-size=\"13\">{title}</text>"
    );
    // Axes, grid and ticks.
    let (xt, yt) = (ticks(x0, x1), ticks(y0, y1));
    let step = |t: &[f64]| if t.len() > 1 { t[1] - t[0] } else { 1.0 };
    for &x in &xt {
        let _ = write!(
            s,
            "<line x1=\"{px:.1}\" y1=\"{top}\" x2=\"{px:.1}\" y2=\"{b}\" stroke=\"#eee\"/>\
<text x=\"{px:.1}\" y=\"{lb}\" text-anchor=\"middle\">{}</text>",
            tick_label(x, step(&xt)),
            px = sx(x),
            b = height - bottom,
            lb = height - bottom + 14.0,
        );
    }
    for &y in &yt {
        let _ = write!(
            s,
            "<line x1=\"{left}\" y1=\"{py:.1}\" x2=\"{r}\" y2=\"{py:.1}\" stroke=\"#eee\"/>\
<text x=\"{tx}\" y=\"{ty:.1}\" text-anchor=\"end\">{}</text>",
            tick_label(y, step(&yt)),
            py = sy(y),
            r = width - right,
            tx = left - 4.0,
            ty = sy(y) + 4.0,
        );
    }
    let _ = write!(
        s,
        "<line x1=\"{left}\" y1=\"{b}\" x2=\"{r}\" y2=\"{b}\" stroke=\"#888\"/>\
<line x1=\"{left}\" y1=\"{top}\" x2=\"{left}\" y2=\"{b}\" stroke=\"#888\"/>\
<text x=\"{cx}\" y=\"{xl}\" text-anchor=\"middle\">{xlabel}</text>\
<text x=\"12\" y=\"{cy}\" text-anchor=\"middle\" transform=\"rotate(-90 12 {cy})\">{ylabel}</text>",
        b = height - bottom,
        r = width - right,
        cx = (left + width - right) / 2.0,
        xl = height - 6.0,
        cy = (top + height - bottom) / 2.0,
    );
    for (k, ser) in drawn.iter().enumerate() {
        let colour = COLOURS[k % COLOURS.len()];
        let mut path = String::new();
        for (i, p) in ser.points.iter().enumerate() {
            let _ = write!(path, "{}{:.1},{:.1} ", if i == 0 { "M" } else { "L" }, sx(p.0), sy(p.1));
        }
        let _ = write!(s, "<path d=\"{path}\" fill=\"none\" stroke=\"{colour}\" stroke-width=\"1.6\"/>");
        // Evaluation points are few: mark each so a reader sees where the curve was measured.
        if ser.points.len() <= 60 {
            for p in &ser.points {
                let _ = write!(s, "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"2.5\" fill=\"{colour}\"/>", sx(p.0), sy(p.1));
            }
        }
        if !ser.name.is_empty() {
            let ly = top + 4.0 + 14.0 * k as f64;
            let _ = write!(
                s,
                "<rect x=\"{lx}\" y=\"{ry:.1}\" width=\"10\" height=\"3\" fill=\"{colour}\"/>\
<text x=\"{tx}\" y=\"{ly:.1}\">{}</text>",
                ser.name,
                lx = left + 10.0,
                ry = ly - 4.0,
                tx = left + 24.0,
            );
        }
    }
    s + "</svg>"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(ticks(0.0, 10.0), vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        let t = ticks(22.3, 33.9);
        assert_eq!(t.first(), Some(&24.0));
        assert!(t.windows(2).all(|w| (w[1] - w[0] - 2.0).abs() < 1e-9), "{t:?}");
        assert_eq!(tick_label(0.25, 0.05), "0.25");
    }

    #[test]
    fn plot_draws_each_series_with_a_legend_and_skips_empty_ones() {
        let a = Series { name: "lego".into(), points: vec![(0.0, 20.0), (5.0, 30.0), (10.0, 32.0)] };
        let b = Series { name: "bowl".into(), points: vec![(0.0, 25.0), (8.0, 33.0)] };
        let empty = Series { name: "none".into(), points: vec![(1.0, 1.0)] };
        let svg = line_plot(&[a, b, empty], "test PSNR", "minutes", "dB", 480.0, 260.0);
        assert_eq!(svg.matches("<path").count(), 2);
        assert_eq!(svg.matches("<circle").count(), 5);
        assert!(svg.contains(">lego<") && svg.contains(">bowl<") && !svg.contains(">none<"));
        assert!(line_plot(&[], "t", "x", "y", 100.0, 100.0).is_empty());
    }
}

//! How dark the foot of a relit object is against the rest of it: per light, the mean colour of
//! the object's lowest quarter of pixels over that of its upper three quarters, over a stage-2
//! run's held-out views.
//!
//! Why: a capture has no relit ground truth, but an object standing on a table should come out
//! darker near the table under a light from above (the table's shadow), and lighter where the
//! table is lit (its bounce). This is the figure `docs/capture.md` sets side by side for stage 2
//! with and without the surroundings.
//!
//! The object's pixels are the capture's masks (`RUN/masks/NNN.png`, white on the object) of the
//! views in `RUN/object/stage2/test/NNN_relit_LIGHT.png`, sorted by row; the lowest quarter is
//! the last 25% of them (ties by column). Colours are the PNGs' sRGB values, averaged over the
//! three channels.
//!
//! Usage: `relit_shadow STAGE2_DIR MASKS_DIR`

use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::Path;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let [_, stage2, masks] = args.as_slice() else {
        bail!("usage: relit_shadow STAGE2_DIR MASKS_DIR");
    };
    let test = Path::new(stage2).join("test");
    // light -> (sum of per-view ratios, views)
    let mut ratios: BTreeMap<String, (f64, usize)> = BTreeMap::new();
    let mut names: Vec<_> = std::fs::read_dir(&test)
        .with_context(|| format!("reading {}", test.display()))?
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("_relit_") && n.ends_with(".png"))
        .collect();
    names.sort();
    for name in names {
        let (view, light) = name.trim_end_matches(".png").split_once("_relit_").context("name")?;
        let img = image::open(test.join(&name)).with_context(|| format!("reading {name}"))?.to_rgb8();
        let mask_path = Path::new(masks).join(format!("{view}.png"));
        let mask = image::open(&mask_path).with_context(|| format!("reading {}", mask_path.display()))?.to_luma8();
        if mask.dimensions() != img.dimensions() {
            bail!("{}: {:?} against the relit {:?}", mask_path.display(), mask.dimensions(), img.dimensions());
        }
        let mut px: Vec<(u32, u32)> =
            mask.enumerate_pixels().filter(|(_, _, m)| m.0[0] >= 128).map(|(x, y, _)| (y, x)).collect();
        if px.len() < 8 {
            bail!("{}: fewer than 8 object pixels", mask_path.display());
        }
        px.sort_unstable();
        let split = px.len() - px.len() / 4;
        let mean = |s: &[(u32, u32)]| {
            s.iter().map(|&(y, x)| img.get_pixel(x, y).0.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0).sum::<f64>()
                / s.len() as f64
        };
        let (upper, lower) = (mean(&px[..split]), mean(&px[split..]));
        let r = ratios.entry(light.to_string()).or_default();
        r.0 += lower / upper.max(1e-9);
        r.1 += 1;
    }
    if ratios.is_empty() {
        bail!("{}: no NNN_relit_LIGHT.png", test.display());
    }
    for (light, (sum, n)) in &ratios {
        println!("{light}: lower quarter / rest {:.3} over {n} views", sum / *n as f64);
    }
    Ok(())
}

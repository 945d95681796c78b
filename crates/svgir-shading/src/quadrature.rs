//! Test-only brute-force quadrature: a stratified grid over the upper hemisphere (z > 0).

use std::f64::consts::PI;

/// `nt x np` cell centres stratified in (cos theta, phi), each with its solid angle
/// `dl = d(cos theta) dphi`; the weights sum to 2pi.
pub(crate) fn stratified_hemisphere(nt: usize, np: usize) -> impl Iterator<Item = ([f64; 3], f64)> {
    let w = 2.0 * PI / (nt * np) as f64;
    (0..nt).flat_map(move |it| {
        let ct = (it as f64 + 0.5) / nt as f64;
        let st = (1.0 - ct * ct).sqrt();
        (0..np).map(move |ip| {
            let phi = 2.0 * PI * (ip as f64 + 0.5) / np as f64;
            ([st * phi.cos(), st * phi.sin(), ct], w)
        })
    })
}

//! One forward + backward vertex-shading pass for instruction counting (callgrind):
//! `cargo run --release -p svgir-pbr --example pbr_profile [N] [reps] [cached|plain] [fwd]` (M = 4, K = 64);
//! the difference of two rep counts isolates the shading from the set-up.

use svgir_pbr::fixtures::Problem;
use svgir_pbr::{shade_backward_cached, shade_into_cached, DirectionCache, ShadeOutput};

fn main() {
    let n: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(2000);
    let (m, k) = (4, 64);
    let problem = Problem::new(n, m, k).unwrap();
    let (inp, g) = (problem.inputs(), &problem.v_color);
    let reps: usize = std::env::args().nth(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let cached = std::env::args().nth(3).is_some_and(|s| s == "cached");
    let cache = cached.then(|| DirectionCache::new(&problem.mb, &problem.env).unwrap());
    let fwd_only = std::env::args().nth(4).is_some_and(|s| s == "fwd");
    let mut out = ShadeOutput::new();
    let mut sum = 0.0f32;
    for _ in 0..reps {
        shade_into_cached(&inp, cache.as_ref(), &mut out).unwrap();
        sum = out.color.iter().sum::<f32>();
        if !fwd_only {
            let grads = shade_backward_cached(&inp, cache.as_ref(), g).unwrap();
            sum += grads.v_env.iter().flatten().sum::<f32>();
        }
    }
    println!("checksum {sum}");
}

//! Diagnostic: the one-bounce radiance SPEC 7 gathers (Eqn 13, `svgir_trace::gather_all`) against
//! the viewer's diffuse PRT estimate `a_h / pi * sum_j L_j T_hj` at the same hits, under the
//! model's learned light, averaged over all (Gaussian, direction) pairs with a hit.
//!
//! `cargo run --release -p svgir-view --example bounce_check -- RUN/stage2/checkpoint.bin`

fn main() {
    let path = std::env::args().nth(1).expect("usage: bounce_check RUN/stage2/checkpoint.bin");
    let s2 = svgir_train::checkpoint::load_stage2(std::path::Path::new(&path)).expect("checkpoint");
    let env = s2.env.radiance();
    let act = s2.materials.activated(&s2.normals).expect("materials");
    let p = svgir_trace::GatherParams {
        env_max: f32::INFINITY,
        lights: None,
        diffuse: s2.config.diffuse,
        cache: None,
        ..Default::default()
    };
    let l1b = svgir_trace::gather_all(&s2.mb, &act.view(), &env, &p).expect("gather");
    let model = svgir_view::model_from_stage2(&s2, &s2.mb, None, 3, false).expect("model");
    let data = svgir_view::VertexData { albedo: &act.albedo, roughness: &act.roughness, normals: &act.normals };
    let escape = svgir_view::model::direct_transfer(&s2.mb, &data, 4, 3, true);
    let sh = svgir_view::light::project_sh(&env, 3, 0.0, 1.0);
    let (m, c, mb) = (4, model.coeffs(), &s2.mb);
    let (mut spec7, mut ours, mut esc, mut count) = ([0.0f64; 3], [0.0f64; 3], [0.0f64; 3], 0usize);
    for i in 0..mb.len() {
        for k in 0..mb.k {
            let Some(h) = mb.hit(i, k) else { continue };
            let h = h as usize;
            let [u, v] = mb.uv(i, k);
            let w = [(1.0 - u) * (1.0 - v), u * (1.0 - v), (1.0 - u) * v, u * v];
            for ch in 0..3 {
                let (mut est, mut est_esc) = (0.0f32, 0.0f32);
                for (vm, wm) in w.iter().enumerate() {
                    let q = h * m + vm;
                    let irr: f32 = (0..c).map(|j| sh[j][ch] * model.transfer[q * c + j]).sum();
                    est += wm * act.albedo[3 * q + ch] / std::f32::consts::PI * irr.max(0.0);
                    let irr: f32 = (0..c).map(|j| sh[j][ch] * escape[q * c + j]).sum();
                    est_esc += wm * act.albedo[3 * q + ch] / std::f32::consts::PI * irr.max(0.0);
                }
                ours[ch] += est as f64;
                esc[ch] += est_esc as f64;
                spec7[ch] += l1b[i * mb.k + k][ch] as f64;
            }
            count += 1;
        }
    }
    let n = count.max(1) as f64;
    println!("{count} hit samples of {}", mb.len() * mb.k);
    println!("mean L1b (SPEC 7 gather): {:?}", spec7.map(|x| x / n));
    println!("mean a/pi * L.T, T visibility-weighted: {:?}", ours.map(|x| x / n));
    println!("mean a/pi * L.E, E over escaping rays (the viewer's --bounce): {:?}", esc.map(|x| x / n));
}

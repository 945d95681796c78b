//! One stage-2 iteration (SPEC 6): the SH pass (or, with `ShadeSets::LastVisit`, only its
//! projection), the PBR pass over the shaded set, Eqn 15's loss with L_rc beside it, the
//! backward through the PBR pass, the shading (on the gradient subset, `gradient_set`) and the
//! activations, and one Adam step per group.
//! The steps are listed in the note of `stage2`; the model and its set-up live there.

use super::*;

impl Stage2 {
    /// The back sides' shading with micro-buffer `mb` (a set of the back's) and its cache.
    fn back_shading<'a>(&'a self, mb: &'a MicroBuffer, cache: &'a DirectionCache) -> BackShading<'a> {
        BackShading { mb, cache: Some(cache), indirect: self.indirect(), lights: self.active_back_lights() }
    }

    /// One stage-2 iteration on a random training view (sun search first when one is due).
    pub fn step(&mut self, dataset: &Dataset) -> Result<Stage2Step, PbrError> {
        let cfg = self.config.clone();
        let wts = &cfg.weights;
        if cfg.lights > 0 && cfg.sun_at > 0 && self.iteration == cfg.sun_at {
            self.concentrate_sun()?;
        }
        if cfg.lights > 0 && self.iteration.is_multiple_of(cfg.lights_every.max(1)) {
            self.set_lights(&brightest_texels(&self.env.radiance(), cfg.lights))?;
        }
        // `search_sun` itself returns None without lights or views.
        let mut sun_search = if self.sun_schedule.due(&cfg, self.iteration) { self.search_sun(dataset)? } else { None };
        if let Some(s) = &mut sun_search {
            s.next_at = self.sun_schedule.searched(&cfg, self.iteration, s.moved_deg);
        }
        let grey = cfg.grey_light.holds(self.iteration + 1, cfg.materials_from);
        if grey {
            self.colour.apply(&mut self.env.param)?;
        }
        self.iteration += 1;
        if !self.photo_corrections.is_empty() && self.photo_corrections.len() != dataset.train.len() {
            return Err(PbrError::InvalidParameter(format!(
                "{} photo colour corrections for {} training photos",
                self.photo_corrections.len(),
                dataset.train.len()
            )));
        }
        let view_index = self.rng.below(dataset.train.len());
        let view = &dataset.train[view_index];
        let bg = cfg
            .background
            .fixed_color()
            .unwrap_or_else(|| [self.rng.uniform(), self.rng.uniform(), self.rng.uniform()]);
        let gt = target_rgb(&view.image, bg);
        let cam = &view.camera;
        let m = cfg.vertices;
        let t0 = Instant::now();

        // 1. SH pass: which Gaussians the view blends (radii and composited weights), and the
        // projection the PBR pass reuses. The loss reads the SH image from the PBR pass
        // (`sh_channels`), so no output of this pass reaches it and it needs no backward (nor
        // keeps lane groups for one, `for_backward`); it skips the depth and normal outputs.
        // With the view's set from its last render (`ShadeSets::LastVisit`), only the
        // projection is made.
        let sh_raster = RasterConfig { geometry: false, for_backward: false, ..self.raster };
        let sh_input = RenderInput {
            surfels: &self.surfels,
            camera: cam,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color(bg),
        };
        let last_set = match cfg.shade_sets {
            ShadeSets::LastVisit => self.view_sets.get(view_index).map(<[u64]>::to_vec),
            ShadeSets::ThisRender => None,
        };
        let sh_pass = || -> Result<_, PbrError> {
            if last_set.is_some() {
                let proj = svgir_raster::try_project(&sh_input, &sh_raster)
                    .map_err(|e| PbrError::InvalidParameter(e.to_string()))?;
                Ok((proj.max_radius(), None, proj))
            } else {
                let (out, state) = render(&sh_input, &sh_raster);
                Ok((out.max_radius, Some(out.accum_weight), state.projected()))
            }
        };
        // The materials do not depend on the SH pass: activated beside it.
        let (sh, act) = rayon::join(sh_pass, || self.materials.activated(&self.normals));
        let (max_radius, sh_weights, sh_proj) = sh?;
        let act = act?;
        let visible = visible_of(&max_radius);
        let (front_vis, back_vis) = self.sides(cam, &visible, self.back.is_some());
        // L_rc is estimated on a random subset of the Gaussians seen on their oriented side
        // (the side the micro-buffers' hits are shaded on).
        let n_visible = front_vis.iter().filter(|v| **v).count();
        let rc_visible: Vec<bool> = if n_visible > cfg.consistency_samples {
            let keep = cfg.consistency_samples as f32 / n_visible as f32;
            front_vis.iter().map(|v| *v && self.rng.uniform() < keep).collect()
        } else {
            front_vis.clone()
        };

        // 2. PBR pass, shading only what the SH pass blended (same surfels and camera).
        let min_w = cfg.shade_min_weight;
        let (front_shade, back_shade, stand_ins) = match (&last_set, &sh_weights) {
            (Some(set), _) => (in_set_of(&front_vis, set), in_set_of(&back_vis, set), Some(outside_set(&visible, set))),
            (None, Some(w)) => (
                weighted(&front_vis, w, min_w),
                weighted(&back_vis, w, min_w),
                (min_w > 0.0).then(|| faint(&visible, w, min_w)),
            ),
            (None, None) => unreachable!("the SH pass renders when the view has no set"),
        };
        let env_rad = self.env.radiance();
        let (front_mb, front_cache) = shading_set(&cfg, self.iteration, &self.mb, &self.dir_cache, &self.subsets);
        let front = Side {
            inputs: ShadeInputs {
                mb: front_mb,
                positions: &self.surfels.positions,
                camera_center: cam.center(),
                visible: &front_shade,
                mats: act.view(),
                env_geom: &env_rad,
                env: &env_rad.data,
                indirect: self.indirect(),
                params: self.shade_params(),
                lights: self.active_lights(),
            },
            cache: Some(front_cache),
        };
        let back_shading = self.back.as_ref().map(|b| {
            let (mb, cache) = shading_set(&cfg, self.iteration, &b.mb, &b.dir_cache, &b.subsets);
            self.back_shading(mb, cache)
        });
        let back_normals = back_shading.as_ref().map(|_| negated(&act.normals));
        let back = render::back_side(&front, back_shading.as_ref(), &back_shade, back_normals.as_deref());
        // The sides the shading's gradients are estimated on: the same, or subsets of the
        // directions (`gradient_directions`).
        let (grad_mb, grad_cache) =
            gradient_set(&cfg, self.iteration, &self.mb, &self.dir_cache, &self.subsets, &self.grad_subsets);
        let front_grad = Side { inputs: ShadeInputs { mb: grad_mb, ..front.inputs }, cache: Some(grad_cache) };
        let back_grad_shading = self.back.as_ref().map(|b| {
            let (mb, cache) = gradient_set(&cfg, self.iteration, &b.mb, &b.dir_cache, &b.subsets, &b.grad_subsets);
            self.back_shading(mb, cache)
        });
        let back_grad =
            render::back_side(&front_grad, back_grad_shading.as_ref(), &back_shade, back_normals.as_deref());
        let mut shaded = ShadeOutput::colour_only();
        // The extra channels (materials, facing normals and the SH colour, `sh_channels`) do
        // not depend on the shading.
        let (shading, (facing, extra)) = rayon::join(
            || self.kernels.shader.shade_sides(&front, back.as_ref(), &mut shaded),
            || {
                let facing = self.facing(cam);
                let extra = pass_features(&act, &facing, sh_proj.sh_colors());
                (facing, extra)
            },
        );
        shading?;
        if let Some(s) = &stand_ins {
            stand_in_colours(sh_proj.sh_colors(), s, m, &mut shaded.color);
        }
        let pbr_input = RenderInput {
            surfels: &self.surfels,
            camera: cam,
            colors: ColorSource::Features(Features { data: &shaded.color, vertices: m, channels: 3, uniform: 0 }),
            extra: Some(Features { data: &extra, vertices: m, channels: PASS_CHANNELS, uniform: SH_CHANNELS }),
            background: Background::Color([0.0; 3]),
        };
        // The loss reads the PBR pass's depth but not its splat normals (the shading normals are
        // feature channels), so that output is not accumulated.
        let pbr_raster = RasterConfig { normals: false, ..self.raster };
        // The PBR pass's Gaussians, camera and settings are the SH pass's (SPEC 6 freezes the
        // geometry; opacities change only at the optimiser's step): a backend may reuse its
        // projection.
        let (pbr_out, pbr_state) =
            self.kernels.raster.render(&pbr_input, &pbr_raster, &sh_proj).map_err(raster_error)?;
        let (materials_out, sh_image) = split_pass(&pbr_out.extra, &pbr_out.alpha, bg);
        let t1 = Instant::now();

        // 3. Eqn 15's per-pixel terms on the PBR image (see `composite`), its material buffers
        // and the SH image (`objective`), then the per-Gaussian ones.
        let cover = photo_coverage(cfg.pbr_coverage, &view.image);
        let correction = self.photo_corrections.get(view_index);
        let target = Stage2Target { rgb: &gt, cover: cover.as_deref(), background: bg, correction };
        let outputs = Stage2Outputs {
            color: &pbr_out.color,
            alpha: &pbr_out.alpha,
            depth: &pbr_out.depth,
            extra: &materials_out,
            sh_color: &sh_image,
        };
        // Radiance consistency (Eqn 14/16).
        let cons_in = ConsistencyInputs {
            mb: &self.mb,
            positions: &self.surfels.positions,
            camera_center: cam.center(),
            visible: &rc_visible,
            mats: act.view(),
            env: &env_rad,
            rho: self.rho,
            params: GatherParams {
                lights: self.active_lights(),
                diffuse: self.config.diffuse,
                cache: Some(&self.dir_cache),
                ..GatherParams::default()
            },
        };
        // The image terms, the consistency term and the per-Gaussian penalties read disjoint
        // inputs, so they run side by side (none alone fills many cores at 256 x 256); the
        // loss adds them in the same order as before.
        let consistency = || -> Result<_, PbrError> {
            if !(cfg.consistency && cfg.indirect) {
                return Ok(None);
            }
            let (c, g) = self.kernels.shader.consistency_with_grad(&cons_in, wts.consistency)?;
            Ok(Some((c.loss, g)))
        };
        let penalties = || (self.materials.offset_penalty(), self.env.tv_l2(self.active_lights().map(|l| l.mask())));
        let (mut obj, (cons, ((reg, v_reg), (tv, v_tv)))) =
            rayon::join(|| stage2_objective(wts, &outputs, &target, cam), || rayon::join(consistency, penalties));
        let mut loss = obj.loss;
        let mut cons_loss = 0.0;
        let cons_grads = cons?.map(|(l, g)| {
            cons_loss = l;
            loss += wts.consistency * l;
            g
        });
        loss += wts.normal_offset * reg;
        loss += wts.env_tv * tv;
        let t2 = Instant::now();

        // 4. Backward: the PBR pass's gives the SH image's gradients too (`sh_channels`).
        let v_pass = join_pass_grads(&obj.v_extra, &obj.v_sh_color, bg, &mut obj.v_alpha);
        let pass = self
            .kernels
            .raster
            .backward(
                &pbr_input,
                &pbr_raster,
                &pbr_state,
                &pbr_out,
                &OutputGrads {
                    color: Some(&obj.v_color),
                    alpha: Some(&obj.v_alpha),
                    depth: Some(&obj.v_depth),
                    normal: None,
                    distortion: None,
                    extra: Some(&v_pass),
                },
            )
            .map_err(raster_error)?;
        let g_pbr = &pass.grads;
        // The shading's gradients are added into L_rc's (the same quantities), or into zeros.
        let mut pg = cons_grads.unwrap_or_else(|| PbrGrads::zeros(self.surfels.len(), m, env_rad.data.len()));
        let (shading, v_sh) = rayon::join(
            || {
                self.kernels.shader.shade_sides_backward(
                    &front_grad,
                    back_grad.as_ref(),
                    &g_pbr.v_color_features,
                    &mut pg,
                )
            },
            || svgir_raster::sh_colors_backward(&sh_input, &sh_proj, &sh_colour_grads(&g_pbr.v_extra, m)),
        );
        let v_sh = v_sh.map_err(|e| PbrError::InvalidParameter(e.to_string()))?;
        shading?;
        extra_features_backward(
            &g_pbr.v_extra,
            PASS_CHANNELS,
            m,
            &facing,
            &mut pg.v_albedo,
            &mut pg.v_roughness,
            &mut pg.v_normals,
        );
        let mg = self.materials.backward(&self.normals, &pg.v_albedo, &pg.v_roughness, &pg.v_normals)?;
        let mut v_offset = mg.v_normal_offset;
        v_offset.par_iter_mut().zip(&v_reg).with_min_len(4096).for_each(|(g, r)| *g += wts.normal_offset * r);
        let mut v_env = self.env.backward(&pg.v_env)?;
        v_env.iter_mut().zip(&v_tv).for_each(|(g, t)| (0..3).for_each(|c| g[c] += wts.env_tv * t[c]));
        let t3 = Instant::now();

        // 5. Adam.
        let g = &mut self.groups;
        g[0].step(&mut self.surfels.opacity_logits, &g_pbr.v_opacity_logits);
        g[1].step(bytemuck::cast_slice_mut(&mut self.surfels.sh), bytemuck::cast_slice(&v_sh));
        if self.iteration > cfg.materials_from {
            g[2].step(&mut self.materials.albedo_raw, &mg.v_albedo_raw);
            g[3].step(&mut self.materials.roughness_raw, &mg.v_roughness_raw);
            g[4].step(&mut self.materials.normal_offset, &v_offset);
            g[5].lr = cfg.lr.env * cfg.env_lr_after_warm_up;
        }
        if grey {
            self.colour.apply(&mut v_env)?;
        }
        g[5].step(bytemuck::cast_slice_mut(&mut self.env.param), bytemuck::cast_slice(&v_env));
        if grey {
            // Adam scales each parameter on its own, which leaves the constrained set.
            self.colour.apply(&mut self.env.param)?;
        }
        if cfg.indirect {
            let mut rho = [self.rho];
            g[6].step(&mut rho, &[pg.v_rho]);
            // rho scales radiance: keep it non-negative.
            self.rho = rho[0].max(0.0);
        }
        if cfg.shade_sets == ShadeSets::LastVisit {
            // The SH pass's weights: the same entries composited with the same alphas.
            self.view_sets.record(view_index, &pass.accum_weight, min_w);
        }
        let t4 = Instant::now();
        let secs = |a: Instant, b: Instant| (b - a).as_secs_f64();
        self.times.forward += secs(t0, t1);
        self.times.loss += secs(t1, t2);
        self.times.backward += secs(t2, t3);
        self.times.optimizer += secs(t3, t4);

        let mse = |a: &[f32]| crate::losses::mse(a, &gt, true);
        Ok(Stage2Step {
            iteration: self.iteration,
            loss,
            psnr_pbr: psnr_of_mse(mse(&obj.image)),
            psnr_sh: psnr_of_mse(mse(&obj.sh_image)),
            consistency: cons_loss,
            rho: self.rho,
            sun_search,
        })
    }
}

//! The fit of the feature normalisation from the training data.

use dynaserve_model::{Body, FeatureFrame, ScenePoints, body_normals, object_params};
use dynaserve_model::{FeatureNormalization, ModelConfig};

use super::seed::rng_for;
use super::sources::Sources;
use super::window::sample_window;
use crate::train::TrainError;
use crate::train::config::DataConfig;

/// Per-feature mean and standard deviation of the raw point features of `model` (contact
/// displacement, per-step increment, offset from the reference cloud, `[ln mass, friction,
/// restitution]`, then the contact velocity, the surface normals and the history if the
/// model takes them) over `c.norm_windows` augmented windows of each of the first
/// `c.norm_scenes` scenes, computed by the model's own
/// [`ScenePoints`]. Standard deviations are floored at 0.01 so constant features do not
/// explode.
pub fn fit_normalization(
    sources: &Sources,
    c: &DataConfig,
    model: &ModelConfig,
    seed: u64,
) -> Result<FeatureNormalization, TrainError> {
    let nf = model.point_features();
    let mut sum = vec![0f64; nf];
    let mut sq = vec![0f64; nf];
    let mut raw = vec![0f32; nf];
    let mut count = 0f64;
    let scenes = sources
        .readers()
        .iter()
        .enumerate()
        .flat_map(|(r, reader)| reader.iter().take(c.norm_scenes).map(move |s| (r, s)));
    for (i, (r, rec)) in scenes.enumerate() {
        let rec = rec?;
        // The first directory keeps the indices (and so the windows) it always had.
        let i = if r == 0 { i } else { i + 1_000_000 * r };
        for w in 0..c.norm_windows {
            let mut rng = rng_for(seed, 4, (i * 1000 + w) as u64);
            let win = sample_window(&rec, c, &mut rng, false, i as u64)?;
            // The partner's mass enters as a ratio, which a scene-wide mass factor leaves as is
            // (kinematic objects aside: scene-relative mass places them at the reference).
            let params: Vec<[f32; 3]> = win
                .objects
                .iter()
                .map(|o| object_params(o.mass, o.friction, o.restitution))
                .collect();
            let bodies: Vec<Body<'_>> = win
                .objects
                .iter()
                .zip(&params)
                .map(|(o, &params)| Body {
                    reference: &o.reference,
                    params,
                })
                .collect();
            let points = ScenePoints::for_model(
                model,
                &bodies,
                || bodies.iter().map(|b| body_normals(b.reference)).collect(),
                &win.state.current,
                &win.state.previous,
                win.state.earlier.as_deref(),
                win.dt_steps,
            );
            for (j, (o, &params)) in win.objects.iter().zip(&params).enumerate() {
                let frame = FeatureFrame::new(
                    &model.dynamics,
                    win.dt_steps,
                    win.state.current[j].translation,
                );
                let first = points.offsets[j];
                for (q, x) in (first..points.offsets[j + 1]).zip(&o.reference) {
                    points.raw_features(q, *x, params, &frame, &model.dynamics, &mut raw);
                    for f in 0..nf {
                        sum[f] += raw[f] as f64;
                        sq[f] += (raw[f] as f64).powi(2);
                    }
                    count += 1.0;
                }
            }
        }
    }
    if count == 0.0 {
        return Err(TrainError::Data(
            "no points to fit the normalisation from".into(),
        ));
    }
    let mut n = FeatureNormalization::defaults_for(&model.dynamics);
    for f in 0..nf {
        let mean = sum[f] / count;
        let var = (sq[f] / count - mean * mean).max(0.0);
        n.mean[f] = mean as f32;
        n.std[f] = (var.sqrt() as f32).max(0.01);
    }
    Ok(n)
}

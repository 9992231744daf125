//! Fields of constant density and colour: scenes built by hand (tests, examples, a
//! placeholder node) whose renders can be computed in closed form.

use crate::config::FieldConfig;
use crate::error::FieldError;
use crate::field::Field;

impl Field {
    /// A small field (4 levels, 2^12 table, no appearance) of constant density `sigma`
    /// (per box diagonal) and colour `rgb` (each in (0, 1); ignored with `view_dependent`): every density weight zero and
    /// the density bias ln σ; every colour weight zero and the last colour bias logit(c).
    /// With `view_dependent`, the colour net keeps its random weights instead, so the
    /// colour depends on the view direction only.
    pub fn constant(
        sigma: f32,
        rgb: [f32; 3],
        view_dependent: bool,
        seed: u64,
    ) -> Result<Field, FieldError> {
        if !(sigma > 0.0 && sigma.is_finite())
            || (!view_dependent && rgb.iter().any(|c| !(*c > 0.0 && *c < 1.0)))
        {
            return Err(FieldError::Config {
                field: "constant".into(),
                message: format!(
                    "expected a finite density above 0 and colours in (0, 1), got {sigma} and {rgb:?}"
                ),
            });
        }
        let mut cfg = FieldConfig::object(0);
        cfg.appearance_dim = 0;
        cfg.log2_table_size = 12;
        cfg.levels = 4;
        let mut f = Field::new(cfg, seed)?;
        let lay = f.layout.clone();
        let zero = |params: &mut [f32], from: usize, len: usize| params[from..from + len].fill(0.0);
        let (d1, d2) = (lay.density[0], lay.density[1]);
        zero(&mut f.params, d1.w, d1.out * d1.inp_pad);
        zero(&mut f.params, d1.b, d1.out);
        zero(&mut f.params, d2.w, d2.out * d2.inp_pad);
        f.params[d2.b] = sigma.ln();
        if !view_dependent {
            for l in &lay.color {
                zero(&mut f.params, l.w, l.out * l.inp_pad);
                zero(&mut f.params, l.b, l.out);
            }
            let last = lay.color.last().expect("colour layers");
            for c in 0..3 {
                f.params[last.b + c] = (rgb[c] / (1.0 - rgb[c])).ln();
            }
        }
        Ok(f)
    }
}

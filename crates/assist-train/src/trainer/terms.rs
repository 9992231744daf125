//! The table of the training loss's terms: each term's name, default weight and meaning,
//! declared once. The objective computes the terms; the weights ([`Lambdas`]), the
//! per-step figures ([`Terms`]), the JSON log, the CLI's flags and Python's keywords are
//! all generated from or iterate over this table, so a new term is one line here and its
//! computation in `objective.rs`.

use serde::Serialize;

/// One row of the table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TermInfo {
    /// The term's name: its key in logs and reports, and `lambda_NAME` for its weight.
    pub name: &'static str,
    /// The weight a run uses unless told otherwise.
    pub default: f32,
    /// Whether users set the weight (`--lambda-NAME`); the photograph term's is fixed at 1.
    pub settable: bool,
    /// What the term asks of the scene, in a sentence or two (the flag's help).
    pub help: &'static str,
}

macro_rules! loss_terms {
    ($( $field:ident : $default:literal, settable: $settable:literal, $help:literal; )*) => {
        /// Every term of the table, in the order the loss sums them.
        pub const TERMS: &[TermInfo] = &[$(TermInfo {
            name: stringify!($field),
            default: $default,
            settable: $settable,
            help: $help,
        }),*];

        /// The weight of each term of the loss (see [`TERMS`] for what each one does).
        #[derive(Debug, Clone, Copy, PartialEq, Serialize)]
        pub struct Lambdas {
            $(pub $field: f32,)*
        }

        impl Default for Lambdas {
            fn default() -> Self {
                Lambdas { $($field: $default,)* }
            }
        }

        /// One value per term: a ray's unweighted terms, or a batch's means.
        #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
        pub struct Terms<T> {
            $(pub $field: T,)*
        }

        impl Lambdas {
            /// The weights in the table's order.
            pub fn values(&self) -> Vec<f32> {
                vec![$(self.$field),*]
            }

            /// The weight of the term called `name`.
            pub fn get_mut(&mut self, name: &str) -> Option<&mut f32> {
                match name {
                    $(stringify!($field) => Some(&mut self.$field),)*
                    _ => None,
                }
            }
        }

        impl<T: Copy> Terms<T> {
            /// Each term with its name, in the table's order.
            pub fn named(&self) -> Vec<(&'static str, T)> {
                vec![$((stringify!($field), self.$field)),*]
            }

            /// Every term mapped through `f`.
            pub fn map<U>(&self, mut f: impl FnMut(T) -> U) -> Terms<U> {
                Terms { $($field: f(self.$field),)* }
            }

            /// Term by term, `f(self, other)`.
            pub fn zip_with(&mut self, other: &Terms<T>, mut f: impl FnMut(&mut T, T)) {
                $(f(&mut self.$field, other.$field);)*
            }
        }

        impl Terms<f64> {
            /// `Σ λ·term`, summed in the table's order.
            pub fn weighted(&self, l: &Lambdas) -> f64 {
                let mut total = 0.0;
                $(total += l.$field as f64 * self.$field;)*
                total
            }
        }
    };
}

loss_terms! {
    comp_rgb: 1.0, settable: false,
        "The composited colour against the photograph (the paper's L_comp_rgb).";
    bg_rgb: 0.5, settable: true,
        "λ1 of the paper: the background's colour against its prior under the objects (0 \
         with --prior none).";
    bg_opacity: 0.0, settable: true,
        "An opaque background behind its prior's depth (ours): where the prior has a depth, \
         the background alone must be opaque past 95% of it, so that what objects hide is \
         learnt as a surface at the prior's depth and not left transparent.";
    bg_clear: 0.0, settable: true,
        "A background clear in front of its prior's depth (ours): on an object's pixels, \
         where the prior has a depth, the background alone must be transparent before 95% \
         of it, so that the object's volume belongs to the object alone (a background that \
         kept part of it leaves a ghost behind once the object moves).";
    bg_depth: 0.1, settable: true,
        "λ2 of the paper: the background's depth against the prior's depth, in units of the \
         scene's extent (0 with --prior none).";
    obj_acc: 0.1, settable: true,
        "λ3 of the paper: each object's opacity against its instance mask.";
    obj_rgb: 0.5, settable: true,
        "λ4 of the paper: each object's own colour inside its mask.";
    obj_share: 0.1, settable: true,
        "The object-share term (ours; 0 gives the paper's loss): inside object k's mask, \
         node k's share of the composited weight must be 1, so that the background cannot \
         grow a copy of the object's surface in front of it.";
    distortion: 0.0, settable: true,
        "The distortion loss of mip-NeRF 360 (Nerfacto's; 0 turns it off): the composited \
         weights of a ray gathered in depth, which removes semi-transparent haze; 0.002 \
         (Nerfacto's) for an unbounded walk-around (--layout).";
    normal: 0.001, settable: true,
        "Ref-NeRF's predicted-normal term, for objects trained with --reflect: each \
         sample's predicted normal against its density's own (the negative gradient), \
         weighed by the sample's share of its ray in the object (Nerfacto's 0.001).";
    empty: 0.0, settable: true,
        "The empty-space term (ours, after Urban Radiance Fields' line-of-sight prior): where \
         the dataset has depth, every node must be empty in front of the surface the depth \
         map sees.";
}

/// The row of the term called `name`.
pub fn term(name: &str) -> Option<&'static TermInfo> {
    TERMS.iter().find(|t| t.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_the_weights_and_the_values_agree() {
        let l = Lambdas::default();
        let names: Vec<&str> = TERMS.iter().map(|t| t.name).collect();
        let defaults: Vec<f32> = TERMS.iter().map(|t| t.default).collect();
        assert_eq!(l.values(), defaults);
        let v = Terms::<f64>::default();
        assert_eq!(v.named().iter().map(|x| x.0).collect::<Vec<_>>(), names);
        let mut l2 = l;
        *l2.get_mut("obj_share").unwrap() = 0.7;
        assert_eq!(l2.obj_share, 0.7);
        assert!(l2.get_mut("nothing").is_none());
        // The weighted total counts each term once with its weight.
        let ones = v.map(|_| 1.0);
        let want: f64 = defaults.iter().map(|d| *d as f64).sum();
        assert!((ones.weighted(&l) - want).abs() < 1e-12);
        assert!(term("comp_rgb").is_some_and(|t| !t.settable));
    }
}

//! Where a field's parameters and a chunk's activations live: the named ranges of the
//! flat parameter vector and the row offsets of one chunk's activations.

use crate::config::FieldConfig;
use crate::hashgrid::GridLayout;
use crate::mlp::Linear;

/// Where each parameter group lives in the flat vector.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamLayout {
    pub grid: GridLayout,
    pub density: [Linear; 2],
    pub color: Vec<Linear>,
    /// Offset of the appearance table (`num_images × appearance_dim`).
    pub appearance: usize,
    pub total: usize,
}

impl ParamLayout {
    pub fn new(cfg: &FieldConfig) -> Self {
        let grid = GridLayout::new(cfg);
        let mut off = grid.param_count();
        let enc = cfg.encoding_width();
        let d1 = Linear::new(cfg.hidden, enc, &mut off);
        let d2 = Linear::new(cfg.density_outputs(), cfg.hidden, &mut off);
        let cin = cfg.geo_features + cfg.sh_width() + cfg.appearance_dim;
        let mut color = vec![Linear::new(cfg.color_hidden, cin, &mut off)];
        for _ in 1..cfg.color_layers {
            color.push(Linear::new(cfg.color_hidden, cfg.color_hidden, &mut off));
        }
        color.push(Linear::new(3, cfg.color_hidden, &mut off));
        let appearance = off;
        off += cfg.num_images * cfg.appearance_dim;
        ParamLayout {
            grid,
            density: [d1, d2],
            color,
            appearance,
            total: off,
        }
    }

    /// Named groups `(name, start, len)`, for serialisation and gradient checks.
    pub fn groups(&self, cfg: &FieldConfig) -> Vec<(String, usize, usize)> {
        let mut g = Vec::new();
        for (i, lv) in self.grid.levels.iter().enumerate() {
            g.push((
                format!("grid.level{i:02}"),
                lv.offset * self.grid.features,
                lv.size as usize * self.grid.features,
            ));
        }
        for (i, l) in self.density.iter().enumerate() {
            g.push((format!("density.{i}.weight"), l.w, l.out * l.inp_pad));
            g.push((format!("density.{i}.bias"), l.b, l.out));
        }
        for (i, l) in self.color.iter().enumerate() {
            g.push((format!("color.{i}.weight"), l.w, l.out * l.inp_pad));
            g.push((format!("color.{i}.bias"), l.b, l.out));
        }
        if cfg.appearance_dim > 0 {
            g.push((
                "appearance".into(),
                self.appearance,
                cfg.num_images * cfg.appearance_dim,
            ));
        }
        g
    }

    /// Start of the MLP + appearance parameters (everything after the grid).
    pub fn mlp_start(&self) -> usize {
        self.grid.param_count()
    }
}

/// Row offsets (in units of CHUNK floats) of one chunk's activations.
#[derive(Debug, Clone)]
pub(super) struct Rows {
    pub(super) hidden: usize,
    pub(super) dens: usize,
    pub(super) cin: usize,
    pub(super) color: Vec<usize>,
    pub(super) rgb: usize,
    pub(super) sigma: usize,
    pub(super) total: usize,
}

impl Rows {
    pub(super) fn new(cfg: &FieldConfig, lay: &ParamLayout) -> Self {
        let mut r = 0;
        let mut take = |n: usize| {
            let o = r;
            r += n;
            o
        };
        let hidden = take(cfg.hidden);
        let dens = take(cfg.density_outputs());
        let cin = take(lay.color[0].inp_pad);
        let color: Vec<usize> = (0..cfg.color_layers)
            .map(|_| take(cfg.color_hidden))
            .collect();
        let rgb = take(3);
        let sigma = take(1);
        Rows {
            hidden,
            dens,
            cin,
            color,
            rgb,
            sigma,
            total: r,
        }
    }
}

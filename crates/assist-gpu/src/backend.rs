//! [`GpuBackend`]: rendering's field queries on a GPU, behind `assist_field::FieldBackend`.
//! Each field met is uploaded once and kept resident; a field whose parameters changed
//! since (training between renders, an edit that replaced it) is uploaded again.

use std::sync::Mutex;

use assist_field::{Field, FieldBackend, FieldQuery, Samples};

use crate::field::{collect, staging_buffer};
use crate::{Gpu, GpuError, GpuField};

/// Fields kept resident at most; past this the least recently used is dropped.
const RESIDENT: usize = 32;

/// Samples per submitted part of a query: bounds the GPU's batch buffers (the encoded
/// features are 128 bytes a sample at Nerfacto's width: 256 MiB).
const PART: usize = 1 << 21;

/// A GPU answering rendering's field queries.
pub struct GpuBackend {
    gpu: std::sync::Arc<Gpu>,
    resident: Mutex<Resident>,
    /// The first failure; the queries after it go to the CPU (see [`FieldBackend::forward`]).
    failed: Mutex<Option<String>>,
    /// Samples per submitted part ([`PART`]; smaller in tests).
    part: usize,
}

#[derive(Default)]
struct Resident {
    fields: Vec<Entry>,
    clock: u64,
    /// Read-back buffers kept between calls (a fresh one costs an allocation the size
    /// of the outputs each time).
    staging: Vec<wgpu::Buffer>,
}

/// Read-back buffers kept at most.
const STAGING: usize = 16;

impl Resident {
    /// A kept read-back buffer for `n` samples (the smallest that fits), or a new one.
    fn staging_for(&mut self, gpu: &Gpu, n: usize) -> Result<wgpu::Buffer, GpuError> {
        let need = 16 * n as u64;
        let best = (0..self.staging.len())
            .filter(|&i| self.staging[i].size() >= need)
            .min_by_key(|&i| self.staging[i].size());
        match best {
            Some(i) => Ok(self.staging.swap_remove(i)),
            None => staging_buffer(gpu, n.next_power_of_two()),
        }
    }

    /// Keeps `bufs` for later calls, the largest [`STAGING`] of all kept.
    fn keep(&mut self, bufs: Vec<wgpu::Buffer>) {
        self.staging.extend(bufs);
        self.staging.sort_by_key(|b| std::cmp::Reverse(b.size()));
        self.staging.truncate(STAGING);
    }
}

struct Entry {
    /// Where the field's parameters live and how many: which field this is.
    at: (usize, usize),
    /// A digest of the parameters (see [`digest`]): whether they changed.
    digest: u64,
    used: u64,
    field: GpuField,
}

impl std::fmt::Debug for GpuBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GpuBackend({})", self.gpu.name())
    }
}

impl GpuBackend {
    pub fn new(gpu: Gpu) -> Self {
        GpuBackend {
            gpu: std::sync::Arc::new(gpu),
            resident: Mutex::default(),
            failed: Mutex::default(),
            part: PART,
        }
    }

    /// [`new`](Self::new) submitting queries in parts of `part` samples, for the tests
    /// of queries larger than a part.
    #[doc(hidden)]
    pub fn with_part(gpu: Gpu, part: usize) -> Self {
        GpuBackend {
            part: part.max(1),
            ..Self::new(gpu)
        }
    }

    /// The GPU, to share (training's optimizers use the same device).
    pub fn gpu(&self) -> &std::sync::Arc<Gpu> {
        &self.gpu
    }

    /// The first error the GPU raised, after which every query ran on the CPU.
    pub fn failure(&self) -> Option<String> {
        self.failed.lock().ok().and_then(|f| f.clone())
    }

    /// The resident copy of `field` (uploaded now if new or changed): its index.
    fn resident(&self, res: &mut Resident, field: &Field) -> Result<usize, GpuError> {
        res.clock += 1;
        let clock = res.clock;
        let at = (field.params.as_ptr() as usize, field.params.len());
        let d = digest(field);
        let k = match res.fields.iter().position(|e| e.at == at) {
            Some(k) if res.fields[k].digest == d => k,
            Some(k) => {
                res.fields[k].field.upload(&self.gpu, field)?;
                res.fields[k].digest = d;
                k
            }
            None => {
                if res.fields.len() >= RESIDENT
                    && let Some(old) = (0..res.fields.len()).min_by_key(|&i| res.fields[i].used)
                {
                    res.fields.swap_remove(old);
                }
                res.fields.push(Entry {
                    at,
                    digest: d,
                    used: clock,
                    field: GpuField::new(&self.gpu, field)?,
                });
                res.fields.len() - 1
            }
        };
        res.fields[k].used = clock;
        Ok(k)
    }

    /// Every query submitted in parts of at most [`PART`] samples, then one wait.
    fn run_all(&self, queries: &mut [FieldQuery<'_>]) -> Result<(), GpuError> {
        let mut res = self.resident.lock().unwrap_or_else(|e| e.into_inner());
        let (mut pending, mut parts) = (Vec::new(), Vec::new());
        for (qi, q) in queries.iter().enumerate() {
            let n = q.samples.len();
            if n == 0 {
                continue;
            }
            let k = self.resident(&mut res, q.field)?;
            res.fields[k].field.set_novel(&self.gpu, q.field, q.novel);
            for a in (0..n).step_by(self.part) {
                let part = slice(&q.samples, a, (a + self.part).min(n));
                let staging = res.staging_for(&self.gpu, part.len())?;
                pending.push(res.fields[k].field.enqueue(&self.gpu, &part, staging)?);
                parts.push((qi, a));
            }
        }
        let bufs = collect(&self.gpu, pending, |j, sigma, rgb| {
            let (qi, a) = parts[j];
            let q = &mut queries[qi];
            q.sigma[a..a + sigma.len()].copy_from_slice(sigma);
            q.rgb[3 * a..3 * a + rgb.len()].copy_from_slice(rgb);
        })?;
        res.keep(bufs);
        Ok(())
    }
}

/// Samples `a..b` of `s` (directions and codes left empty where they are).
fn slice<'a>(s: &Samples<'a>, a: usize, b: usize) -> Samples<'a> {
    let part = |v: &'a [f32]| if v.is_empty() { v } else { &v[a..b] };
    Samples {
        pos: s.pos.map(|p| &p[a..b]),
        dir: s.dir.map(part),
        image: if s.image.is_empty() {
            s.image
        } else {
            &s.image[a..b]
        },
    }
}

impl FieldBackend for GpuBackend {
    fn name(&self) -> String {
        self.gpu.name()
    }

    fn forward(
        &self,
        field: &Field,
        s: &Samples,
        sigma: &mut [f32],
        rgb: &mut [f32],
    ) -> Result<(), String> {
        self.forward_all(&mut [FieldQuery {
            field,
            samples: *s,
            novel: None,
            sigma,
            rgb,
        }])
    }

    /// On the first error the backend records it and declines every later query (the
    /// caller then queries on the CPU), so one bad adapter costs one message, not a
    /// render.
    fn forward_all(&self, queries: &mut [FieldQuery<'_>]) -> Result<(), String> {
        if let Some(e) = self.failure() {
            return Err(e);
        }
        self.run_all(queries).map_err(|e| {
            let msg = e.to_string();
            let mut failed = self.failed.lock().unwrap_or_else(|e| e.into_inner());
            failed.get_or_insert(msg.clone());
            msg
        })
    }
}

/// A digest of `field`'s parameters: every value past the hash grid (the nets, the
/// appearance codes: every training step changes these) and 8,192 of the grid's spread
/// evenly, with its length. Cheap next to a batch's query, and changed by any step.
pub(crate) fn digest(field: &Field) -> u64 {
    let p = &field.params;
    let grid = field.layout.grid.param_count().min(p.len());
    let stride = (grid / 8192).max(1);
    let mut h: u64 = 0xcbf2_9ce4_8422_2325 ^ p.len() as u64;
    let mut eat = |v: f32| {
        h ^= v.to_bits() as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    };
    p[..grid].iter().step_by(stride).for_each(|&v| eat(v));
    p[grid..].iter().for_each(|&v| eat(v));
    h
}

//! A run's peak memory, estimated before it starts (`prism recon --dry-run` prints it; `recon`
//! refuses a run above the memory available unless `--allow-memory`).
//!
//! Every method holds the scene (projections and reference volumes) and its output volumes
//! throughout. On top of that comes the largest of three phases whose buffers never coexist:
//! [`INITIALISATION`] (a learned method's FDK), [`TRAINING`] (below; scoring during training
//! included when the log scores), and [`SCORING`] (the final scores, [`run_footprint`]).
//! Training holds, per channel (channels run one after another):
//! * classic methods: the filtered projections or residuals of one channel and a few volumes;
//!   `tv` holds every channel at once (primal, extrapolated and step volumes, the gradient duals,
//!   and a data dual with its steps per training ray);
//! * Gaussian methods: the Gaussians with their gradients and Adam moments, the iteration's
//!   transient tensors (per Gaussian, per detector pixel, per TV-patch voxel). The Gaussian count is not known before training: the estimate is given
//!   at the densification cap (`densify.max_gaussians`, what a run may reach) and is the one
//!   compared with the memory available;
//! * NAF: the hash grid's tables with their Adam moments and one batch of samples.
//!
//! The per-item constants were measured with `/usr/bin/time -v` (peak resident size) on runs of
//! known size; see [`GAUSSIAN_BYTES`] and [`prism_domain::memory::PROCESS_BYTES`].

use crate::algorithms::sart::{block_count, caches_column_sums};
use crate::device::DeviceChoice;
use crate::methods::classic::ClassicMethod;
use crate::methods::naf::rays::TrainRay;
use crate::{Method, MethodConfig};
use prism_domain::memory::{Footprint, bytes};
use prism_domain::scene::Scene;

/// Bytes per Gaussian at a training iteration's peak, plus 16 per density column: the
/// parameters with gradients and two Adam moments, the render's per-Gaussian preparation, band
/// and slab lists and the autodiff graph's saved tensors. Measured: the slope of peak resident
/// size against the Gaussian count on `prism bench scaling`'s 128³ scene (25 views, 128², 3
/// channels; 100 000 → 500 000 Gaussians): R²-Gaussian 0.97 kB per Gaussian with its three
/// channels (530 bytes and the pages kept per further channel, [`RETAINED_PER_CHANNEL`], beside
/// the finished channels' checkpoint state), 4D-SG 0.53 kB with its 3 density columns. It was
/// 800 (1.0 and 0.82 kB measured) while the render's backward passes kept a partial sum per
/// (tile, Gaussian); 1 980 before that, measured on one channel at 64³ / 96².
pub const GAUSSIAN_BYTES: u64 = 530;

/// What a Gaussian method's training holds whatever its Gaussian count and grid: the autodiff
/// graph's and the render's fixed buffers, per-thread scratch, the allocator's retained arenas.
/// Measured: the intercept of peak resident size over `prism bench scaling`'s whole sweep (46
/// runs, 64³–256³, 64²–512², 13–100 views, 2–8 channels), fitted with the terms below; 40 MB
/// before, when the grid-sized pages of a finished channel's voxelisation
/// ([`FINISHED_CHANNEL_VOXEL_BYTES`]) and the training targets ([`TARGET_BYTES`]) were not counted,
/// read R²-Gaussian 33 % and 4D-SG 29 % high at 64³.
pub const GAUSSIAN_FIXED_BYTES: u64 = 10_000_000;

/// R²-Gaussian trains the channels one after another; pages the allocator keeps from one channel
/// stay resident beside the next channel's (they are handed back lazily, see the binary's
/// allocator settings). Measured as a fraction of one channel's Gaussian working set per further
/// channel: phantom-4mono, 500 iterations (K up to 61 618): 232 MB peak against 185 MB without
/// this term, after the one-channel calibration above had the rest 8 MB high: 0.148.
pub const RETAINED_PER_CHANNEL: f64 = 0.148;

/// Bytes per voxel and channel of 4D-SG's final volumes: every channel is voxelised at once
/// (the model's output tensor, its host copy, the per-channel volumes, the voxelizer's padded
/// slab buffers: 4 × 4 bytes), and the allocator still holds those pages (freed lazily) while
/// the channels are scored. Measured with `prism bench scaling`: 4D-SG's peak against the
/// channel count (2 → 8 channels at 128³) grows by 32–34 bytes per voxel and channel, of which
/// the scene's reference and the output volume are 8. At 12 (three buffers) 8 channels read
/// 21 % low.
pub const VOXELISED_BYTES: u64 = 16;

/// A reconstruction process beyond [`prism_domain::memory::PROCESS_BYTES`]: `prism recon` on a
/// 16³ scene (16² detector, 13 views) peaks at 30 MB with FDK, SART or CGLS and 34 MB with
/// R²-Gaussian (100 Gaussians), `prism info` on it at 14 MB.
pub const RECON_BYTES: u64 = 10_000_000;

/// Bytes per detector pixel of one view at an iteration's peak whatever the channel count (the
/// SSIM term's maps, the loss's scratch), and per rendered column ([`COLUMN_PIXEL_BYTES`]: the
/// image and its gradient). Measured: the slope of peak against the detector's pixels (64² →
/// 512²) beyond the scene's projections, R²-Gaussian (one column) 360 and 4D-SG (three) 410
/// bytes; one 200-byte constant per column read R²-Gaussian 11 % low and 4D-SG 17 % high.
pub const PIXEL_BYTES: u64 = 100;

/// Bytes per detector pixel and rendered column at an iteration's peak, see [`PIXEL_BYTES`].
pub const COLUMN_PIXEL_BYTES: u64 = 50;

/// Bytes per pixel of every training view and column: the training targets as tensors beside the
/// scene's own copy. Measured: the slope of peak against the view count (13 → 100) beyond the
/// scene, 9 (R²-Gaussian, one column) and 16 bytes (4D-SG, three) per pixel and view.
pub const TARGET_BYTES: u64 = 8;

/// R²-Gaussian voxelises each channel when its training ends; the allocator keeps those pages (the
/// output tensor, its host copy, the voxelizer's slab buffers) while the next channel trains.
/// Measured: the slope of peak against the grid (64³ → 256³) above the scene and outputs, 3
/// channels: about 12 bytes per voxel more than a one-channel run holds during training.
pub const FINISHED_CHANNEL_VOXEL_BYTES: u64 = 12;

/// The share of the training's Gaussian working set still resident while 4D-SG voxelises and
/// scores every channel (pages freed lazily). Measured: 4D-SG's final-scoring peak against the
/// Gaussian count (10 000 → 100 000 at 128³, where scoring is the peak) grows by 0.28 kB per
/// Gaussian, 0.5 of the 0.58 kB working set; 0.75 keeps 8 channels (the largest scoring phase
/// swept) within 5 %. Counting all of it read 4D-SG 23 % high at 100 000 Gaussians.
pub const RESIDENT_GAUSSIAN_SHARE: f64 = 0.75;

pub use crate::evaluate::protocol::VOXEL_BYTES;

/// The phases of a run whose buffers never coexist (each one's are freed before the next
/// starts): the peak is what the run holds throughout plus the largest of them.
pub const INITIALISATION: &str = "initialisation";
pub const TRAINING: &str = "training";
pub const SCORING: &str = "the final scoring";

/// The estimated peak memory of a run as `prism recon` and a suite cell make it: [`footprint`]
/// and, when the scene has references, scoring them under `evaluation` (the only volume-sized
/// scoring buffers: [`footprint`] itself leaves them out, so they are counted once).
pub fn run_footprint(
    config: &MethodConfig,
    scene: &Scene,
    evaluation: &crate::evaluate::Evaluation,
) -> Footprint {
    let mut peak = footprint(config, scene);
    if scene.references.is_some() {
        evaluation
            .protocol
            .add_footprint(&mut peak, SCORING, scene.geometry.volume.len());
    }
    peak
}

/// The estimated peak memory of running `config` on `scene` (Gaussian methods at their
/// densification cap; `--set densify.max_gaussians=K` gives the estimate at K Gaussians).
pub fn footprint(config: &MethodConfig, scene: &Scene) -> Footprint {
    let g = &scene.geometry;
    let voxels = g.volume.len();
    let (rows, cols) = (g.detector.rows, g.detector.cols);
    let channels = scene.n_channels();
    let views = scene.n_views();
    let train = scene.split.train.len();
    let mut f = Footprint::process();
    f.add(
        "the reconstruction's own (thread pools, kernels' tables)",
        RECON_BYTES,
    );
    f.add(
        format!("the scene: projections ({channels} × {views} views × {rows}×{cols})"),
        bytes(scene.projections.len(), 4),
    );
    if let Some(r) = &scene.references {
        f.add("the scene: reference volumes", bytes(r.len(), 4));
    }
    if let Some(m) = &scene.materials {
        f.add("the scene: material fractions", bytes(m.fractions.len(), 4));
    }
    f.add(
        format!("output volumes ({channels} × {voxels} voxels)"),
        bytes(voxels, 4 * channels),
    );
    let view_pixels = rows * cols;
    match config {
        MethodConfig::Classic(c) => {
            f.add_in(
                TRAINING,
                "one channel's filtered projections or residuals",
                bytes(train * view_pixels, 8),
            );
            f.add_in(
                TRAINING,
                "working volumes",
                bytes(voxels, VOXEL_BYTES as usize),
            );
            if c.method == ClassicMethod::Sart {
                let blocks = block_count(train, c.block_size);
                let kept = if caches_column_sums(blocks, voxels) {
                    blocks
                } else {
                    1
                };
                f.add_in(
                    TRAINING,
                    format!("SART's column sums ({kept} of {blocks} blocks kept)"),
                    bytes(voxels, 4 * kept),
                );
            }
            if c.method == ClassicMethod::Tv {
                f.add_in(
                    TRAINING,
                    format!("TV's primal, step and gradient-dual volumes ({channels} channels)"),
                    bytes(voxels, 4 * 6 * channels),
                );
                f.add_in(
                    TRAINING,
                    "TV's data duals and their steps (every channel's training rays)",
                    bytes(train * view_pixels, 8 * channels),
                );
            }
        }
        // Below, from the geometry stage's settings.
        MethodConfig::R2gs(_) | MethodConfig::FourDsg(_) => {}
        MethodConfig::Naf(c) => {
            add_fdk(&mut f, voxels, train * view_pixels);
            let h = &c.field.hash_grid;
            let table = h.levels * (1usize << h.log2_table_size.min(40)) * h.features;
            f.add_in(
                TRAINING,
                "hash-grid tables with gradients and Adam moments",
                bytes(table, 16),
            );
            f.add_in(
                TRAINING,
                format!(
                    "one channel's training rays ({train} views × {rows}×{cols} pixels at most)"
                ),
                bytes(train * view_pixels, std::mem::size_of::<TrainRay>()),
            );
            let samples = c.rays_per_batch.saturating_mul(c.samples_per_ray);
            // On the CPU the MLP is one fused op whose activations live per 512-point task: a
            // sample holds its point, its output, and five encoding-sized buffers (the
            // encodings and their gradient are two, the encoder's own buffers the rest; measured:
            // the peak less the scene, the outputs and the other items, 64³ to 160³ at 128²,
            // 65 MB for 98 304 samples). On wgpu the MLP is composed of tensor ops, every layer's
            // activations kept for the backward.
            let per_sample = match c.device {
                DeviceChoice::Cpu => 4 * (5 * h.levels * h.features + 8),
                DeviceChoice::Wgpu => 8 * (c.field.width * c.field.layers + h.levels * h.features),
            };
            // The log scores a channel between iterations, when the batch's buffers are freed:
            // the larger of the two counts.
            let batch = bytes(samples, per_sample);
            let scores = if scene.references.is_some() {
                bytes(voxels, VOXEL_BYTES as usize)
            } else {
                0
            };
            f.add_in(
                TRAINING,
                if scores > batch {
                    TRAINING_SCORES.to_string()
                } else {
                    format!(
                        "one batch of {samples} samples through the field (forward and backward)"
                    )
                },
                batch.max(scores),
            );
        }
    }
    if let Some(c) = config.geometry() {
        let k = c
            .densify
            .as_ref()
            .map_or(c.init.n_points, |d| d.max_gaussians.max(c.init.n_points));
        let columns = match config.method() {
            Method::FourDsg => channels,
            _ => 1,
        };
        // The Gaussians with their gradients, Adam moments and an iteration's transients.
        let gaussians = bytes(k, (GAUSSIAN_BYTES + 16 * columns as u64) as usize);
        f.add(
            "the Gaussian training's fixed buffers (graph, scratch, retained arenas)",
            GAUSSIAN_FIXED_BYTES,
        );
        add_fdk(&mut f, voxels, train * view_pixels);
        if c.eval_every > 0 && scene.references.is_some() {
            add_training_scores(&mut f, voxels);
        }
        f.add_in(
            TRAINING,
            format!(
                "{k} Gaussians (at the densification cap; {} at the start), with gradients, \
                 Adam moments and an iteration's transients",
                c.init.n_points
            ),
            gaussians,
        );
        if config.method() == Method::R2gs && channels > 1 {
            let working = bytes(k, GAUSSIAN_BYTES as usize) as f64;
            f.add_in(
                TRAINING,
                format!(
                    "pages kept from earlier channels ({} × {:.0} % of the Gaussians' working \
                     set)",
                    channels - 1,
                    100.0 * RETAINED_PER_CHANNEL
                ),
                ((channels - 1) as f64 * RETAINED_PER_CHANNEL * working) as u64,
            );
            f.add_in(
                TRAINING,
                "a finished channel's voxelisation, still resident (freed lazily)",
                bytes(voxels, FINISHED_CHANNEL_VOXEL_BYTES as usize),
            );
        }
        // The checkpoints keep every finished geometry stage's parameters and Adam moments
        // on the host: 3 × 4 bytes for each of a Gaussian's 11 parameters.
        let finished = match config.method() {
            Method::R2gs => channels - 1,
            _ => 1,
        };
        if finished > 0 {
            f.add_in(
                TRAINING,
                format!("{finished} finished stages' state kept for checkpoints"),
                bytes(k, 12 * 11 * finished),
            );
        }
        if let MethodConfig::FourDsg(c) = config
            && c.spectral.stage2.residual.is_some()
        {
            // Value, gradient and two Adam moments of every residual, and the curve plus it.
            f.add_in(
                TRAINING,
                format!("channel residuals ({k} Gaussians × {channels} channels)"),
                bytes(k, 20 * channels),
            );
        }
        if let MethodConfig::FourDsg(c) = config {
            // Upper bounds (both scale as the network does; exact at the default size is not
            // needed, a width that cannot fit must not pass): 16·width² parameters per block
            // (projections and the SSM's matrices) with gradients and two Adam moments, and
            // per evaluated node and channel 8 width-sized activations per block.
            let m = &c.spectral.stage2.curve_model;
            let depth = m.depth.max(1);
            let params = m.width.saturating_mul(m.width).saturating_mul(16 * depth);
            let nodes = if m.table_size == 0 {
                k
            } else {
                m.table_size + 2
            };
            let acts = nodes
                .saturating_mul(channels)
                .saturating_mul(m.width)
                .saturating_mul(8 * depth);
            f.add_in(
                TRAINING,
                format!(
                    "the curve model (width {}, depth {depth}): parameters with gradients and \
                     Adam moments, activations at {nodes} nodes × {channels} channels",
                    m.width
                ),
                bytes(params, 16).saturating_add(bytes(acts, 4)),
            );
        }
        f.add_in(
            TRAINING,
            format!("an iteration's images and loss maps ({columns} × {rows}×{cols})"),
            bytes(
                view_pixels,
                (PIXEL_BYTES + COLUMN_PIXEL_BYTES * columns as u64) as usize,
            ),
        );
        f.add_in(
            TRAINING,
            format!("the training targets ({columns} × {train} views × {rows}×{cols})"),
            bytes(
                train * view_pixels,
                (TARGET_BYTES * columns as u64) as usize,
            ),
        );
        if config.method() == Method::FourDsg {
            f.add_in(
                SCORING,
                format!(
                    "every channel voxelised at once ({channels} × {voxels} voxels: the model's \
                     output, its host copy and the per-channel volumes)"
                ),
                bytes(voxels, (VOXELISED_BYTES * channels as u64) as usize),
            );
            // Measured: without it 4D-SG with 8 channels at 128³ read 25 % low.
            f.add_in(
                SCORING,
                format!(
                    "the training's Gaussian pages, {:.0} % still resident (freed lazily)",
                    100.0 * RESIDENT_GAUSSIAN_SHARE
                ),
                (gaussians as f64 * RESIDENT_GAUSSIAN_SHARE) as u64,
            );
        }
    }
    f
}

/// The FDK a learned method starts from (its density scale, and the Gaussians' initial
/// positions): the volume and one channel's filtered projections, freed before training.
fn add_fdk(f: &mut Footprint, voxels: usize, train_pixels: usize) {
    f.add_in(
        INITIALISATION,
        "the FDK initialisation (volume and its filtered projections)",
        bytes(voxels, 8).saturating_add(bytes(train_pixels, 4)),
    );
}

const TRAINING_SCORES: &str =
    "scoring one channel during training (its volume, the normalised copies)";

/// Scoring a channel during training (the log's PSNR and SSIM every `eval_every` iterations),
/// beside the training state.
fn add_training_scores(f: &mut Footprint, voxels: usize) {
    f.add_in(
        TRAINING,
        TRAINING_SCORES,
        bytes(voxels, VOXEL_BYTES as usize),
    );
}

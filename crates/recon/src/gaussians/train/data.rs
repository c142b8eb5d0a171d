//! What a stage fits: the training views as tensors (normalised line integrals) with their
//! cameras in the normalised world.

use crate::gaussians::World;
use burn::tensor::{Device, Int, Tensor, TensorData};
use ndarray::{ArrayView3, Axis};
use prism_domain::geometry::Geometry;
use prism_domain::scene::Scene;
use prism_render::Camera;

/// One training view: its camera (normalised world) and the supervised density columns.
pub struct View {
    pub camera: Camera,
    /// Normalised line integrals `[1, n, rows, cols]` of the supervised columns.
    pub target: Tensor<4>,
    /// The density columns supervised here, when not all of them.
    pub columns: Option<Columns>,
}

/// The density columns a view supervises (increasing): on the host, and as the index tensor that
/// selects them from a rendered view.
pub struct Columns {
    pub list: Vec<usize>,
    pub index: Tensor<1, Int>,
}

impl Columns {
    pub fn new(list: Vec<usize>, device: &Device) -> Columns {
        let idx: Vec<i64> = list.iter().map(|&i| i as i64).collect();
        let index = Tensor::<1, Int>::from_data(TensorData::new(idx, [list.len()]), device);
        Columns { list, index }
    }
}

/// What a stage fits: views and the number of density columns the model renders.
pub struct Supervision {
    pub views: Vec<View>,
    pub columns: usize,
}

impl Supervision {
    /// Training views with one image per listed view: `images[i]` is `[n][rows][cols]` (measured
    /// line integrals, mm⁻¹·mm) of view `views[i]` of `geometry`, `columns[i]` the supervised
    /// density columns (None: all `total_columns`).
    pub fn new(
        geometry: &Geometry,
        world: &World,
        views: &[usize],
        images: Vec<Vec<f32>>,
        columns: Vec<Option<Vec<usize>>>,
        total_columns: usize,
        device: &Device,
    ) -> Supervision {
        let g = world.geometry(geometry);
        let (rows, cols) = (geometry.detector.rows, geometry.detector.cols);
        let f = world.projection_factor() as f32;
        let views = views
            .iter()
            .zip(images)
            .zip(columns)
            .map(|((&v, img), c)| {
                let n = img.len() / (rows * cols);
                View {
                    camera: g.camera(v),
                    target: target_tensor(
                        img.iter().map(|x| x * f).collect(),
                        n,
                        rows,
                        cols,
                        device,
                    ),
                    columns: c.map(|c| Columns::new(c, device)),
                }
            })
            .collect();
        Supervision {
            views,
            columns: total_columns,
        }
    }

    /// One density column supervised at every listed view with the full image.
    pub fn single(
        geometry: &Geometry,
        world: &World,
        views: &[usize],
        images: Vec<Vec<f32>>,
        device: &Device,
    ) -> Supervision {
        let all = vec![None; views.len()];
        Supervision::new(geometry, world, views, images, all, 1, device)
    }
}

/// Every measured channel of a scene at every training view that has one: what a stage fitting
/// all channels supervises ([`Supervision::new`] with `columns` and the scene's channel count).
pub struct Measured {
    pub views: Vec<usize>,
    /// Per view, its measured channels' images in channel order (`[n][rows][cols]`).
    pub images: Vec<Vec<f32>>,
    /// Per view, its measured channels when not all of them.
    pub columns: Vec<Option<Vec<usize>>>,
}

impl Measured {
    pub fn of(scene: &Scene) -> Measured {
        let m = scene.n_channels();
        let (mut views, mut images, mut columns) = (Vec::new(), Vec::new(), Vec::new());
        for &v in scene.train_views() {
            let avail = scene.available_channels(v);
            if avail.is_empty() {
                continue;
            }
            let img = avail
                .iter()
                .flat_map(|&c| image(scene.channel_projections(c), v))
                .collect();
            views.push(v);
            images.push(img);
            columns.push((avail.len() < m).then_some(avail));
        }
        Measured {
            views,
            images,
            columns,
        }
    }
}

/// View `v` of a `[view][row][col]` stack, row-major.
pub fn image(p: ArrayView3<f32>, v: usize) -> Vec<f32> {
    p.index_axis(Axis(0), v).iter().copied().collect()
}

/// Upload a `[n][rows][cols]` stack of normalised line integrals as `[1, n, rows, cols]`.
pub fn target_tensor(
    values: Vec<f32>,
    n: usize,
    rows: usize,
    cols: usize,
    device: &Device,
) -> Tensor<4> {
    Tensor::from_data(TensorData::new(values, [1, n, rows, cols]), device)
}

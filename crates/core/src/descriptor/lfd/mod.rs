//! The Light Field Descriptor (Chen, Tian, Shen, Ouhyoung, "On visual similarity based 3D
//! model retrieval", Eurographics 2003): the view-based baseline of the paper's comparison
//! (SPEC §6, paper §6.2 and Fig. 14).
//!
//! Two models look alike when their silhouettes from corresponding directions look alike. A
//! *light field* is the set of 10 silhouettes seen from the vertices of a dodecahedron around
//! the normalised model ([`cameras`]); each silhouette ([`silhouette`]) is described by 35
//! Zernike moment magnitudes ([`zernike`]) and 10 Fourier descriptors of its contour
//! ([`contour`]), each quantised to 8 bits as in the paper. A model keeps 10 light fields
//! from 10 turns of the camera system, so that some pair of them is nearly aligned whatever
//! the two models' orientations.
//!
//! Distance: for two light fields, the least sum of image L1 distances over the 60 rotations
//! of the dodecahedron (which permute the views); for two models, the least over the 10 × 10
//! pairs of light fields. Pairs are visited in order of a lower bound from the view sums
//! ([`LfdSummary`]) until none can beat the best found; a visited pair's 10 × 10 image
//! distances — u8 abs-diff sums, `psadbw` — are computed first; the least cell of each row
//! (or column) summed bounds all 60 rotations, and most pairs stop there; otherwise each
//! rotation costs ten table look-ups, and stops as soon as its partial sum reaches the best.

pub mod cameras;
pub mod contour;
pub mod silhouette;
pub mod zernike;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::mesh::PreparedMesh;
pub use cameras::{Cameras, LIGHT_FIELDS, ROTATIONS, VIEWS};
pub use contour::{fourier_descriptors, FOURIER_COUNT};
pub use silhouette::{Silhouette, IMAGE_SIZE};
pub use zernike::{zernike_magnitudes, ZERNIKE_COUNT};

/// Quantised coefficients per image: 35 Zernike + 10 Fourier.
pub const COEFFICIENTS: usize = ZERNIKE_COUNT + FOURIER_COUNT;
/// Images per model.
pub const IMAGES: usize = LIGHT_FIELDS * VIEWS;
/// Bytes of a descriptor's coefficients, unpadded ([`LightFieldDescriptor::packed`]).
pub const PACKED: usize = IMAGES * COEFFICIENTS;
/// Bytes per image in memory: padded so that distance loops run on whole vector registers.
const PADDED: usize = 48;
/// The largest light-field distance: every coefficient of every view at opposite ends.
const MAX_DISTANCE: f64 = (VIEWS * COEFFICIENTS * 255) as f64;

/// One silhouette's features, quantised: `⌊256·x⌋` (at most 255) for the Zernike magnitudes,
/// `⌊512·x⌋` for the Fourier descriptors, as in Chen et al.'s code (their Fourier
/// descriptors are small, so they are doubled first).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(into = "Vec<u8>", try_from = "Vec<u8>")]
pub struct ImageFeatures([u8; PADDED]);

impl ImageFeatures {
    /// The features of one silhouette.
    pub fn of(image: &Silhouette) -> Self {
        let quantise = |x: f64, scale: f64| (x * scale).clamp(0.0, 255.0) as u8;
        let mut bytes = [0u8; PADDED];
        for (b, z) in bytes.iter_mut().zip(zernike_magnitudes(image)) {
            *b = quantise(z, 256.0);
        }
        for (b, f) in bytes[ZERNIKE_COUNT..]
            .iter_mut()
            .zip(fourier_descriptors(image))
        {
            *b = quantise(f, 512.0);
        }
        Self(bytes)
    }

    /// The 45 coefficients.
    pub fn coefficients(&self) -> &[u8] {
        &self.0[..COEFFICIENTS]
    }

    /// L1 distance: three `psadbw`s (SSE2, part of every x86-64) over the padded array. The
    /// plain loop compiled to widening adds several times as long, and a ranking's LFD
    /// distances compute millions of these.
    #[cfg(target_arch = "x86_64")]
    fn l1(&self, other: &Self) -> u32 {
        use std::arch::x86_64::{
            __m128i, _mm_add_epi64, _mm_cvtsi128_si32, _mm_sad_epu8, _mm_shuffle_epi32,
        };
        let (a, b): ([__m128i; 3], [__m128i; 3]) =
            (bytemuck::cast(self.0), bytemuck::cast(other.0));
        // SAFETY: SSE2 intrinsics on values, no memory touched; every x86-64 target has SSE2.
        // Each 64-bit lane of a `psadbw` holds a sum of at most 8 · 255.
        unsafe {
            let sum = _mm_add_epi64(
                _mm_add_epi64(_mm_sad_epu8(a[0], b[0]), _mm_sad_epu8(a[1], b[1])),
                _mm_sad_epu8(a[2], b[2]),
            );
            let sum = _mm_add_epi64(sum, _mm_shuffle_epi32::<0b01_00_11_10>(sum));
            _mm_cvtsi128_si32(sum) as u32
        }
    }

    /// L1 distance over the padded array.
    #[cfg(not(target_arch = "x86_64"))]
    fn l1(&self, other: &Self) -> u32 {
        self.0
            .iter()
            .zip(&other.0)
            .map(|(&a, &b)| a.abs_diff(b) as u32)
            .sum()
    }
}

impl From<ImageFeatures> for Vec<u8> {
    fn from(f: ImageFeatures) -> Self {
        f.coefficients().to_vec()
    }
}

impl TryFrom<Vec<u8>> for ImageFeatures {
    type Error = String;
    fn try_from(v: Vec<u8>) -> Result<Self, String> {
        if v.len() != COEFFICIENTS {
            return Err(format!(
                "an image has {COEFFICIENTS} coefficients, not {}",
                v.len()
            ));
        }
        let mut bytes = [0u8; PADDED];
        bytes[..COEFFICIENTS].copy_from_slice(&v);
        Ok(Self(bytes))
    }
}

/// A model's light field descriptor: [`LIGHT_FIELDS`] × [`VIEWS`] images, light field major,
/// views in [`Cameras::axes`] order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(into = "Vec<ImageFeatures>", try_from = "Vec<ImageFeatures>")]
pub struct LightFieldDescriptor {
    images: Vec<ImageFeatures>,
}

impl From<LightFieldDescriptor> for Vec<ImageFeatures> {
    fn from(d: LightFieldDescriptor) -> Self {
        d.images
    }
}

impl TryFrom<Vec<ImageFeatures>> for LightFieldDescriptor {
    type Error = String;
    fn try_from(images: Vec<ImageFeatures>) -> Result<Self, String> {
        if images.len() != IMAGES {
            return Err(format!(
                "a light field descriptor has {IMAGES} images, not {}",
                images.len()
            ));
        }
        Ok(Self { images })
    }
}

impl LightFieldDescriptor {
    /// Renders the prepared (normalised) mesh from all 100 directions and describes each
    /// silhouette. The views are independent, so they run in parallel; each is deterministic,
    /// so the result does not depend on the thread count.
    pub fn compute(mesh: &PreparedMesh) -> Self {
        let cameras = Cameras::get();
        let images = (0..IMAGES)
            .into_par_iter()
            .map(|i| {
                let axis = cameras.direction(i / VIEWS, i % VIEWS);
                ImageFeatures::of(&Silhouette::render(&mesh.positions, &mesh.triangles, axis))
            })
            .collect();
        Self { images }
    }

    /// The coefficients of every image, in order, without padding.
    pub fn packed(&self) -> [u8; PACKED] {
        let mut packed = [0u8; PACKED];
        for (out, image) in packed.chunks_exact_mut(COEFFICIENTS).zip(&self.images) {
            out.copy_from_slice(image.coefficients());
        }
        packed
    }

    /// The inverse of [`LightFieldDescriptor::packed`].
    pub fn unpacked(packed: &[u8; PACKED]) -> Self {
        let images = packed
            .chunks_exact(COEFFICIENTS)
            .map(|c| {
                let mut bytes = [0u8; PADDED];
                bytes[..COEFFICIENTS].copy_from_slice(c);
                ImageFeatures(bytes)
            })
            .collect();
        Self { images }
    }

    /// Per light field, each coefficient summed over its views: what [`LfdSummary`] keeps.
    pub fn summary(&self) -> LfdSummary {
        let mut sums: Sums = [[0; PADDED]; LIGHT_FIELDS];
        for (field, sum) in sums.iter_mut().enumerate() {
            for image in self.light_field(field) {
                for (s, &c) in sum.iter_mut().zip(image.coefficients()) {
                    // At most 10 · 255.
                    *s += c as u16;
                }
            }
        }
        LfdSummary(sums)
    }

    /// The [`LfdSketch`] of this descriptor.
    pub fn sketch(&self) -> LfdSketch {
        self.summary().sketch()
    }

    /// The images of light field `field`.
    pub fn light_field(&self, field: usize) -> &[ImageFeatures] {
        &self.images[field * VIEWS..(field + 1) * VIEWS]
    }

    /// Distance between two models, in [0, 1]: the least, over the 10 × 10 pairs of light
    /// fields and the 60 rotations aligning their views, of the summed image L1 distances,
    /// divided by its largest possible value.
    pub fn distance(&self, other: &Self) -> f64 {
        LfdQuery::new(self)
            .distance_within(other, &other.summary(), f64::INFINITY)
            .unwrap_or(1.0)
    }
}

/// One side of many light-field distances, prepared once: a ranking compares its query with
/// thousands of entries, and each comparison needs the query's summary and the sorted views
/// of its light fields ([`sorted_views`]).
pub struct LfdQuery<'a> {
    descriptor: &'a LightFieldDescriptor,
    summary: LfdSummary,
    sorted: [[ImageFeatures; VIEWS]; LIGHT_FIELDS],
}

/// The light-field pairs a distance visits ([`LfdQuery::pairs`]): those whose summary bound is
/// within its limit, the least sum past the cutoff.
pub struct Pairs {
    pairs: [(u32, u8, u8); LIGHT_FIELDS * LIGHT_FIELDS],
    within: usize,
    limit: u32,
}

impl<'a> LfdQuery<'a> {
    pub fn new(descriptor: &'a LightFieldDescriptor) -> Self {
        Self {
            descriptor,
            summary: descriptor.summary(),
            sorted: std::array::from_fn(|field| sorted_views(descriptor.light_field(field))),
        }
    }

    /// The query's summary.
    pub fn summary(&self) -> &LfdSummary {
        &self.summary
    }

    /// [`LightFieldDescriptor::distance`] to `other`, whose summary is `theirs`, or `None` when
    /// it exceeds `cutoff`.
    pub fn distance_within(
        &self,
        other: &LightFieldDescriptor,
        theirs: &LfdSummary,
        cutoff: f64,
    ) -> Option<f64> {
        self.distance(self.pairs(theirs, cutoff)?, other)
    }

    /// The light-field pairs whose summary bound (see [`LfdSummary`]) is within `cutoff` of a
    /// model summarised by `theirs`, for [`LfdQuery::distance`]; `None` when there are none,
    /// so the distance is past `cutoff` without the other descriptor (a ranking reads it from
    /// a file).
    pub fn pairs(&self, theirs: &LfdSummary, cutoff: f64) -> Option<Pairs> {
        // The least sum past the cutoff: sums reaching it are abandoned like those reaching
        // the best so far.
        let limit = match cutoff {
            c if c < 0.0 => return None,
            c if c >= 1.0 => u32::MAX,
            c => {
                let mut sum = (c * MAX_DISTANCE) as u32;
                while sum as f64 / MAX_DISTANCE <= c {
                    sum += 1;
                }
                while sum > 0 && (sum - 1) as f64 / MAX_DISTANCE > c {
                    sum -= 1;
                }
                sum
            }
        };
        // Only the pairs whose bound is within the limit are visited: most of a ranking's
        // calls end past its cutoff, and then few are.
        let bounds = pair_bounds(&self.summary.0, &theirs.0);
        let mut pairs = [(0u32, 0u8, 0u8); LIGHT_FIELDS * LIGHT_FIELDS];
        let mut within = 0;
        for (p, row) in bounds.iter().enumerate() {
            for (q, &bound) in row.iter().enumerate() {
                pairs[within] = (bound, p as u8, q as u8);
                within += usize::from(bound < limit);
            }
        }
        (within > 0).then_some(Pairs {
            pairs,
            within,
            limit,
        })
    }

    /// The distance to `other` over the light-field pairs that [`LfdQuery::pairs`] found
    /// within the cutoff for `other`'s summary, or `None` past the cutoff. The pairs are
    /// visited in order of their bound, and the visit stops at the first that cannot beat the
    /// best sum found or the cutoff: usually a few of the 100, each costing 100 image
    /// distances and 60 rotations.
    pub fn distance(&self, pairs: Pairs, other: &LightFieldDescriptor) -> Option<f64> {
        let permutations = &Cameras::get().permutations;
        let Pairs {
            mut pairs,
            within,
            limit,
        } = pairs;
        let pairs = &mut pairs[..within];
        pairs.sort_unstable();
        let mut best = limit;
        let mut their_sorted = [None; LIGHT_FIELDS];
        for &mut (bound, p, q) in pairs {
            if bound >= best {
                break;
            }
            let (p, q) = (p as usize, q as usize);
            let rows = self.descriptor.light_field(p);
            let columns = other.light_field(q);
            // The sorted views bound this pair more tightly than the sums ordering the visit,
            // for a tenth of the pair's own cost.
            let ours = &self.sorted[p];
            let theirs = their_sorted[q].get_or_insert_with(|| sorted_views(columns));
            let sorted: u32 = ours.iter().zip(theirs.iter()).map(|(a, b)| a.l1(b)).sum();
            if sorted >= best {
                continue;
            }
            let mut table = [[0u16; VIEWS]; VIEWS];
            for (row, a) in table.iter_mut().zip(rows) {
                for (cell, b) in row.iter_mut().zip(columns) {
                    // At most 45 · 255 = 11 475.
                    *cell = a.l1(b) as u16;
                }
            }
            // Every rotation takes one cell of each row and of each column: the rows' least
            // cells, or the columns', bound them all.
            let mut column_least = [u16::MAX; VIEWS];
            let mut row_least = 0u32;
            for row in &table {
                row_least += *row.iter().min().expect("ten views") as u32;
                for (least, &cell) in column_least.iter_mut().zip(row) {
                    *least = (*least).min(cell);
                }
            }
            let column_least: u32 = column_least.iter().map(|&c| c as u32).sum();
            if row_least.max(column_least) >= best {
                continue;
            }
            for permutation in permutations {
                let mut sum = 0u32;
                for (row, &v) in table.iter().zip(permutation) {
                    sum += row[v as usize] as u32;
                    if sum >= best {
                        break;
                    }
                }
                best = best.min(sum);
            }
        }
        (best < limit || limit == u32::MAX).then(|| best as f64 / MAX_DISTANCE)
    }
}

/// Comparators of a sorting network of 10 inputs (Waksman 1969; 29 of them).
const SORT_10: [(usize, usize); 29] = [
    (4, 9),
    (3, 8),
    (2, 7),
    (1, 6),
    (0, 5),
    (1, 4),
    (6, 9),
    (0, 3),
    (5, 8),
    (0, 2),
    (3, 6),
    (7, 9),
    (0, 1),
    (2, 4),
    (5, 7),
    (8, 9),
    (1, 2),
    (4, 6),
    (7, 8),
    (3, 5),
    (2, 5),
    (6, 8),
    (1, 3),
    (4, 7),
    (2, 3),
    (6, 7),
    (3, 4),
    (5, 6),
    (4, 5),
];

/// A light field's views with each coefficient's values sorted across them: for any
/// rotation `π`, `Σ_v ‖A_v − B_π(v)‖₁ ≥ Σ_v ‖sort(A)_v − sort(B)_v‖₁`, since on each
/// coefficient the least-cost matching of two sets of numbers pairs them in sorted order.
/// Sorted by a network of lane-wise min/max, which vectorises over the coefficients.
fn sorted_views(field: &[ImageFeatures]) -> [ImageFeatures; VIEWS] {
    let mut views: [ImageFeatures; VIEWS] = std::array::from_fn(|v| field[v]);
    for (i, j) in SORT_10 {
        let (a, b) = (views[i].0, views[j].0);
        views[i] = ImageFeatures(std::array::from_fn(|c| a[c].min(b[c])));
        views[j] = ImageFeatures(std::array::from_fn(|c| a[c].max(b[c])));
    }
    views
}

/// L1 distance of two padded vectors of sums: six packed 16-bit abs-diffs (saturating
/// subtractions both ways) summed by `pmaddwd`, all SSE2, part of every x86-64; the
/// autovectoriser made of the plain loop twice as many narrower steps, and the summary bound
/// runs for every entry of a ranking.
#[cfg(target_arch = "x86_64")]
fn sums_l1(a: &[u16; PADDED], b: &[u16; PADDED]) -> u32 {
    use std::arch::x86_64::{
        __m128i, _mm_add_epi32, _mm_cvtsi128_si32, _mm_madd_epi16, _mm_or_si128, _mm_set1_epi16,
        _mm_setzero_si128, _mm_shuffle_epi32, _mm_subs_epu16,
    };
    let (a, b): ([__m128i; 6], [__m128i; 6]) = (bytemuck::cast(*a), bytemuck::cast(*b));
    // SAFETY: the intrinsics need SSE2, which every x86-64 target has (it is in the baseline
    // the compiler itself assumes); they touch no memory. A difference is at most 10 · 255,
    // so `pmaddwd`'s signed 16-bit view of it is exact.
    unsafe {
        let ones = _mm_set1_epi16(1);
        let sum = (0..6).fold(_mm_setzero_si128(), |sum, k| {
            let d = _mm_or_si128(_mm_subs_epu16(a[k], b[k]), _mm_subs_epu16(b[k], a[k]));
            _mm_add_epi32(sum, _mm_madd_epi16(d, ones))
        });
        let sum = _mm_add_epi32(sum, _mm_shuffle_epi32::<0b01_00_11_10>(sum));
        let sum = _mm_add_epi32(sum, _mm_shuffle_epi32::<0b10_11_00_01>(sum));
        _mm_cvtsi128_si32(sum) as u32
    }
}

/// L1 distance of two padded vectors of sums.
#[cfg(not(target_arch = "x86_64"))]
fn sums_l1(a: &[u16; PADDED], b: &[u16; PADDED]) -> u32 {
    a.iter().zip(b).map(|(&x, &y)| x.abs_diff(y) as u32).sum()
}

/// Per light field, each coefficient's view sum: [`LfdSummary`]'s values.
type Sums = [[u16; PADDED]; LIGHT_FIELDS];

/// [`sums_l1`] of each of the 10 × 10 light-field pairs, with AVX2 where the processor has it
/// (detected at run time): two of its steps do the work of six SSE2 steps, and a ranking
/// computes these for tens of thousands of entries.
fn pair_bounds(a: &Sums, b: &Sums) -> [[u32; LIGHT_FIELDS]; LIGHT_FIELDS] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2.
        return unsafe { pair_bounds_avx2(a, b) };
    }
    std::array::from_fn(|p| std::array::from_fn(|q| sums_l1(&a[p], &b[q])))
}

/// [`pair_bounds`] in 256-bit steps: [`sums_l1`]'s subtractions and `pmaddwd` on 16 lanes.
///
/// # Safety
/// The processor must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn pair_bounds_avx2(a: &Sums, b: &Sums) -> [[u32; LIGHT_FIELDS]; LIGHT_FIELDS] {
    use std::arch::x86_64::{
        __m256i, _mm256_add_epi32, _mm256_castsi256_si128, _mm256_extracti128_si256,
        _mm256_madd_epi16, _mm256_or_si256, _mm256_set1_epi16, _mm256_setzero_si256,
        _mm256_subs_epu16, _mm_add_epi32, _mm_cvtsi128_si32, _mm_shuffle_epi32,
    };
    let theirs: [[__m256i; 3]; LIGHT_FIELDS] = bytemuck::cast(*b);
    let ones = _mm256_set1_epi16(1);
    let mut bounds = [[0u32; LIGHT_FIELDS]; LIGHT_FIELDS];
    for (row, ours) in bounds.iter_mut().zip(a) {
        let x: [__m256i; 3] = bytemuck::cast(*ours);
        for (bound, y) in row.iter_mut().zip(&theirs) {
            // As in `sums_l1`: a difference is at most 10 · 255, exact in `pmaddwd`.
            let mut sum = _mm256_setzero_si256();
            for k in 0..3 {
                let d =
                    _mm256_or_si256(_mm256_subs_epu16(x[k], y[k]), _mm256_subs_epu16(y[k], x[k]));
                sum = _mm256_add_epi32(sum, _mm256_madd_epi16(d, ones));
            }
            let sum = _mm_add_epi32(
                _mm256_castsi256_si128(sum),
                _mm256_extracti128_si256::<1>(sum),
            );
            let sum = _mm_add_epi32(sum, _mm_shuffle_epi32::<0b01_00_11_10>(sum));
            let sum = _mm_add_epi32(sum, _mm_shuffle_epi32::<0b10_11_00_01>(sum));
            *bound = _mm_cvtsi128_si32(sum) as u32;
        }
    }
    bounds
}

/// A lower bound on [`LightFieldDescriptor::distance`] from 10 × 45 sums, for ranking without
/// computing most distances. Any rotation only permutes views, so for light fields `A`, `B`
/// and each coefficient, `Σ_v |A_v − B_π(v)| ≥ |Σ_v A_v − Σ_v B_v|` (triangle inequality):
/// the L1 distance of the view sums bounds every rotation's sum, and the least over light
/// field pairs bounds the model distance.
///
/// Kept for every indexed model (960 bytes): the ranking computes the bound for every entry.
/// Sums rounded to bytes would halve that but prune less (on SHREC'07 with the 10th
/// neighbour's distance: 42 % of the pairs instead of 54 %), and an LFD distance costs a few
/// hundred bounds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LfdSummary(Sums);

impl LfdSummary {
    /// Each light field's coefficient sums over its views, scaled so that the L1 distance of
    /// two fields' is their term of [`LfdSummary::lower_bound`].
    pub fn fields(&self) -> impl Iterator<Item = [f32; COEFFICIENTS]> + '_ {
        self.0
            .iter()
            .map(|sums| std::array::from_fn(|c| (f64::from(sums[c]) / MAX_DISTANCE) as f32))
    }

    /// The [`LfdSketch`] of the descriptor summarised.
    pub fn sketch(&self) -> LfdSketch {
        LfdSketch::of(self)
    }

    /// The sums, light field by light field, without padding: a compact form to keep apart
    /// from the descriptor ([`crate::rank::compact`]).
    pub fn sums(&self) -> Vec<u16> {
        self.0
            .iter()
            .flat_map(|s| s[..COEFFICIENTS].to_vec())
            .collect()
    }

    /// The inverse of [`LfdSummary::sums`]; `None` for sums of another length.
    pub fn from_sums(sums: &[u16]) -> Option<Self> {
        if sums.len() != LIGHT_FIELDS * COEFFICIENTS {
            return None;
        }
        let mut padded: Sums = [[0; PADDED]; LIGHT_FIELDS];
        for (field, sums) in padded.iter_mut().zip(sums.chunks_exact(COEFFICIENTS)) {
            field[..COEFFICIENTS].copy_from_slice(sums);
        }
        Some(Self(padded))
    }

    /// Never above the distance of the descriptors summarised.
    pub fn lower_bound(&self, other: &Self) -> f64 {
        let bounds = pair_bounds(&self.0, &other.0);
        let best = bounds.as_flattened().iter().min().expect("pairs");
        *best as f64 / MAX_DISTANCE
    }
}

/// Groups of coefficients an [`LfdSketch`] sums: the Zernike magnitudes in runs of six (and
/// a last of five), the Fourier descriptors in two runs of five. Neighbouring orders move
/// together, so their differences rarely cancel within a group.
const GROUPS: [std::ops::Range<usize>; SKETCH_GROUPS] = [
    0..6,
    6..12,
    12..18,
    18..24,
    24..30,
    30..ZERNIKE_COUNT,
    ZERNIKE_COUNT..ZERNIKE_COUNT + 5,
    ZERNIKE_COUNT + 5..COEFFICIENTS,
];
const SKETCH_GROUPS: usize = 8;
/// Lanes of a sketch row: the light fields, padded to a whole AVX2 register of `u16`.
const LANES: usize = 16;

/// A coarser lower bound than [`LfdSummary`]'s, at an eighth of its cost, for the first pass
/// over every entry of a ranking. Per light field, the view sums of [`LfdSummary`] are summed
/// again over [`GROUPS`] of coefficients, and `Σ_c |A_c − B_c| ≥ Σ_g |Σ_{c∈g} A_c − Σ_{c∈g}
/// B_c|` (triangle inequality), so the least over light-field pairs of the groups' L1 distance
/// never exceeds the summary's bound, hence the distance.
///
/// Laid out group-major with the light fields in lanes (256 bytes), so that one query light
/// field is compared with all of an entry's at once.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LfdSketch([[u16; LANES]; SKETCH_GROUPS]);

impl LfdSketch {
    fn of(summary: &LfdSummary) -> Self {
        // Lanes past the light fields hold the largest value: any difference to them
        // saturates the sum, so they never are the least.
        let mut groups = [[u16::MAX; LANES]; SKETCH_GROUPS];
        for (field, sums) in summary.0.iter().enumerate() {
            for (row, range) in groups.iter_mut().zip(GROUPS) {
                // At most 6 · 10 · 255.
                row[field] = sums[range].iter().sum();
            }
        }
        Self(groups)
    }

    /// Never above [`LfdSummary::lower_bound`] of the same descriptors, so never above their
    /// distance.
    pub fn lower_bound(&self, other: &Self) -> f64 {
        sketch_bound(&self.0, (&other.0, &other.0)) as f64 / MAX_DISTANCE
    }

    /// Never above [`LfdSketch::lower_bound`] with any sketch in `span`.
    pub fn span_bound(&self, span: &SketchSpan) -> f64 {
        sketch_bound(&self.0, (&span.least, &span.greatest)) as f64 / MAX_DISTANCE
    }
}

/// The least and the greatest of each value over a set of [`LfdSketch`]es: a box holding
/// them, as [`crate::descriptor::Span`] is for vectors.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SketchSpan {
    least: [[u16; LANES]; SKETCH_GROUPS],
    greatest: [[u16; LANES]; SKETCH_GROUPS],
}

impl SketchSpan {
    pub fn of(sketch: &LfdSketch) -> Self {
        Self {
            least: sketch.0,
            greatest: sketch.0,
        }
    }

    pub fn widen(&mut self, sketch: &LfdSketch) {
        for ((least, greatest), row) in self.least.iter_mut().zip(&mut self.greatest).zip(&sketch.0)
        {
            for ((l, g), &x) in least.iter_mut().zip(greatest.iter_mut()).zip(row) {
                (*l, *g) = ((*l).min(x), (*g).max(x));
            }
        }
    }
}

/// The least over light fields `a` of `query` and lanes of an entry of the summed group
/// differences, the entry's values anywhere between `least` and `greatest` (equal for one
/// entry): each difference is the distance to that interval, `least − x` or `x − greatest`
/// saturated at 0, which is `|x − y|` when they are `y`. Sums saturate at `u16::MAX`, which
/// only lowers a bound. Plain lane loops that the compiler vectorises, built for AVX2 and
/// chosen at run time where the processor has it (the SSE2 baseline otherwise).
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn sketch_bound(query: &[[u16; LANES]; SKETCH_GROUPS], (least, greatest): SketchSide) -> u16 {
    let mut best = [u16::MAX; LANES];
    for field in 0..LIGHT_FIELDS {
        let mut sum = [0u16; LANES];
        for ((low, high), q) in least.iter().zip(greatest).zip(query) {
            let x = q[field];
            for ((s, &l), &h) in sum.iter_mut().zip(low).zip(high) {
                *s = s.saturating_add(l.saturating_sub(x).max(x.saturating_sub(h)));
            }
        }
        for (b, s) in best.iter_mut().zip(sum) {
            *b = (*b).min(s);
        }
    }
    best.into_iter().min().unwrap_or(u16::MAX)
}

/// One side of a sketch bound: an entry's sketch twice, or a [`SketchSpan`]'s least and
/// greatest values.
type SketchSide<'a> = (
    &'a [[u16; LANES]; SKETCH_GROUPS],
    &'a [[u16; LANES]; SKETCH_GROUPS],
);

#[cfg(test)]
mod tests {
    use super::*;

    /// Each pair's bound is the plain L1 distance of the sums, on whichever path the
    /// processor takes (AVX2 on the machines this runs on), at the sums' extremes too.
    #[test]
    fn pair_bounds_are_the_sums_l1_distances() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(45);
        let most = (VIEWS * 255) as u16;
        for trial in 0..20 {
            let mut sums = || -> Sums {
                std::array::from_fn(|_| {
                    let mut row = [0u16; PADDED];
                    for s in &mut row[..COEFFICIENTS] {
                        *s = match trial {
                            0 => most,
                            1 => 0,
                            _ => rng.gen_range(0..=most),
                        };
                    }
                    row
                })
            };
            let (a, b) = (sums(), if trial < 2 { [[0; PADDED]; 10] } else { sums() });
            let bounds = pair_bounds(&a, &b);
            for p in 0..LIGHT_FIELDS {
                for q in 0..LIGHT_FIELDS {
                    let plain: u32 = a[p]
                        .iter()
                        .zip(&b[q])
                        .map(|(&x, &y)| x.abs_diff(y) as u32)
                        .sum();
                    assert_eq!(bounds[p][q], plain, "trial {trial}, pair {p} {q}");
                }
            }
        }
    }

    /// The 0-1 principle: a comparator network sorts every input if it sorts every input of
    /// zeros and ones.
    #[test]
    fn the_network_sorts_every_input() {
        for bits in 0..1u32 << VIEWS {
            let field: Vec<ImageFeatures> = (0..VIEWS)
                .map(|v| ImageFeatures([(bits >> v & 1) as u8; PADDED]))
                .collect();
            let sorted = sorted_views(&field);
            assert!(sorted.windows(2).all(|w| w[0].0 <= w[1].0), "{bits:010b}");
        }
    }
}

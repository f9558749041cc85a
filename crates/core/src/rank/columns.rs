//! The index's entries, stored by column in chunks.
//!
//! A ranking's first pass reads one or two small values of every entry (the LFD sketch, the
//! geodesic sums, the D2 histogram): kept in per-chunk arrays, that pass streams through
//! memory instead of following a pointer per entry into a heap of 100 000 signatures (on
//! real signatures, a pass over `Arc`ed entries cost ~0.7 µs an entry, almost all of it cache
//! and TLB misses). Chunks are shared between copies of the index (`Arc`) and copied on
//! write, so publishing a changed copy copies one or two chunks, not the whole index.

use std::io;
use std::sync::Arc;

use rayon::prelude::*;

use crate::descriptor::geodesic::Cumulative;
use crate::descriptor::lfd::{LfdSketch, LfdSummary, SketchSpan};
use crate::descriptor::{GeodesicDescriptor, LightFieldDescriptor, Span};
use crate::params::SimilarityParams;
use crate::signature::Signature;
use crate::similarity::{Centroid, Features, Summary};

use super::compact::Compact;
use super::shelf::Slot;
use super::{Compared, Held, Method};

/// Entries per chunk: a copy on write moves about a megabyte.
const CHUNK: usize = 1024;

/// Entries per block ([`BlockSpan`]), a divisor of [`CHUNK`]: entry `i` is in block
/// `i / BLOCK`.
pub const BLOCK: usize = 32;

/// What the entries of a block hold, as boxes: a bound on a query's distance to all of them
/// at once, which rejects the block when it is past a k-th distance. A part's box is `None`
/// once an entry lacks the part (or has it at another length), and bounds leave it out. An
/// entry replaced or taken out stays in the boxes, which then hold more than they must: still
/// bounds, only looser, until the index is arranged again ([`super::Index::arrange`]).
#[derive(Debug, Clone)]
pub struct BlockSpan {
    geodesic: Option<Span>,
    /// The ECC and region-D2 means, and the least and greatest feature counts: `None` once an
    /// entry has no features.
    centroid: Option<(Span, Span, (usize, usize))>,
    sketch: Option<SketchSpan>,
}

impl BlockSpan {
    fn of(entry: Parts) -> Self {
        let [geodesic, ecc, d2] = entry.vectors;
        Self {
            geodesic: geodesic.map(Span::of),
            centroid: ecc.zip(d2).map(|(ecc, d2)| {
                (
                    Span::of(ecc),
                    Span::of(d2),
                    (entry.features, entry.features),
                )
            }),
            sketch: entry.sketch.map(SketchSpan::of),
        }
    }

    fn widen(&mut self, entry: Parts) {
        fn keep<T>(part: &mut Option<T>, widened: impl FnOnce(&mut T) -> bool) {
            if part.as_mut().is_some_and(|p| !widened(p)) {
                *part = None;
            }
        }
        let [geodesic, ecc, d2] = entry.vectors;
        keep(&mut self.geodesic, |span| {
            geodesic.is_some_and(|g| span.widen(g))
        });
        let count = entry.features;
        keep(
            &mut self.centroid,
            |(ecc_span, d2_span, (least, greatest))| {
                (*least, *greatest) = ((*least).min(count), (*greatest).max(count));
                ecc.zip(d2)
                    .is_some_and(|(ecc, d2)| ecc_span.widen(ecc) && d2_span.widen(d2))
            },
        );
        keep(&mut self.sketch, |span| {
            entry.sketch.inspect(|s| span.widen(s)).is_some()
        });
    }

    pub fn geodesic(&self) -> Option<&Span> {
        self.geodesic.as_ref()
    }

    /// The boxes of the ECC and region-D2 means, and the feature counts' range.
    pub fn centroid(&self) -> Option<CentroidSpans<'_>> {
        let (ecc, d2, counts) = self.centroid.as_ref()?;
        Some(((ecc, d2), *counts))
    }

    pub fn sketch(&self) -> Option<&SketchSpan> {
        self.sketch.as_ref()
    }
}

/// The boxes of a block's ECC and region-D2 means, and its least and greatest feature counts:
/// [`crate::similarity::centroid_span_bound`]'s side.
pub type CentroidSpans<'a> = ((&'a Span, &'a Span), (usize, usize));

/// What the hybrid's first bound compares of an entry: what [`BlockSpan`] boxes and
/// [`super::arrange`] orders by.
#[derive(Clone, Copy)]
pub struct Parts<'a> {
    /// The geodesic descriptor's cumulative sums, then the ECC and region-D2 means (`None`
    /// without features).
    pub vectors: [Option<&'a [f32]>; 3],
    pub features: usize,
    pub sketch: Option<&'a LfdSketch>,
}

impl<'a> Parts<'a> {
    fn new(
        geodesic: Option<&'a Cumulative>,
        (ecc, d2, features): (&'a [f32], &'a [f32], usize),
        sketch: Option<&'a LfdSketch>,
    ) -> Self {
        let with_features = features > 0;
        Self {
            vectors: [
                geodesic.map(Cumulative::values),
                with_features.then_some(ecc),
                with_features.then_some(d2),
            ],
            features,
            sketch,
        }
    }
}

/// Histograms of one chunk in one array, at a common stride (the longest row), each with its
/// own length: what a full pass reads, without a pointer per row.
#[derive(Debug, Clone, Default)]
struct Rows {
    stride: usize,
    values: Vec<f32>,
    lengths: Vec<u32>,
}

impl Rows {
    fn get(&self, slot: usize) -> &[f32] {
        let start = slot * self.stride;
        &self.values[start..start + self.lengths[slot] as usize]
    }

    fn set(&mut self, slot: usize, row: &[f32]) {
        if row.len() > self.stride {
            self.widen(row.len());
        }
        if slot == self.lengths.len() {
            self.lengths.push(0);
            self.values.resize(self.values.len() + self.stride, 0.0);
        }
        let start = slot * self.stride;
        self.values[start..start + row.len()].copy_from_slice(row);
        self.lengths[slot] = row.len() as u32;
    }

    /// Restrides every row to `stride` (rare: a histogram longer than any before it).
    fn widen(&mut self, stride: usize) {
        let mut values = vec![0.0; stride * self.lengths.len()];
        for (slot, &length) in self.lengths.iter().enumerate() {
            let (from, to) = (slot * self.stride, slot * stride);
            values[to..to + length as usize]
                .copy_from_slice(&self.values[from..from + length as usize]);
        }
        (self.stride, self.values) = (stride, values);
    }

    /// Takes the last row out.
    fn pop(&mut self) -> Vec<f32> {
        let last = self.lengths.len() - 1;
        let row = self.get(last).to_vec();
        self.lengths.pop();
        self.values.truncate(self.lengths.len() * self.stride);
        row
    }
}

/// Up to [`CHUNK`] entries, one array per column.
#[derive(Debug, Clone, Default)]
struct Chunk {
    ids: Vec<Arc<str>>,
    features: Vec<Features>,
    light_fields: Vec<Option<Arc<Slot>>>,
    summaries: Vec<Summary>,
    sketches: Vec<Option<LfdSketch>>,
    lfd: Vec<Option<LfdSummary>>,
    geodesic: Vec<Option<Cumulative>>,
    d2: Rows,
    ecc_mean: Rows,
    d2_mean: Rows,
    /// One per [`BLOCK`] of entries.
    spans: Vec<BlockSpan>,
}

/// What the index keeps of one model, computed once when it is inserted.
pub struct Row {
    id: Arc<str>,
    features: Features,
    light_field: Option<Arc<Slot>>,
    d2: Vec<f32>,
    summary: Summary,
    centroid: (Vec<f32>, Vec<f32>),
    sketch: Option<LfdSketch>,
    lfd: Option<LfdSummary>,
    geodesic: Option<Cumulative>,
}

impl Row {
    /// `light_field` is the model's light field descriptor kept (`signature.lfd` shelved, or
    /// kept away when the signature comes without it) and its summary.
    pub fn new(
        id: Arc<str>,
        signature: &Signature,
        light_field: Option<(Arc<Slot>, LfdSummary)>,
        params: &SimilarityParams,
    ) -> Self {
        let (slot, lfd) = light_field.unzip();
        let compact = Compact {
            features: Features::of(&signature.features),
            d2: signature.d2.clone(),
            geodesic: (signature.geodesic.as_ref()).map(GeodesicDescriptor::cumulative),
            lfd,
        };
        Self::compact(id, compact, slot, params)
    }

    /// The row of a model's [`compact`](super::compact) form, its descriptor kept as
    /// `light_field` says.
    pub(crate) fn compact(
        id: Arc<str>,
        compact: Compact,
        light_field: Option<Arc<Slot>>,
        params: &SimilarityParams,
    ) -> Self {
        let Compact {
            features,
            d2,
            geodesic,
            lfd,
        } = compact;
        Self {
            centroid: features.centroid(),
            summary: Summary::of(&features, params),
            features,
            sketch: lfd.as_ref().map(LfdSummary::sketch),
            lfd,
            light_field,
            d2,
            geodesic,
            id,
        }
    }

    pub fn id(&self) -> &Arc<str> {
        &self.id
    }

    fn parts(&self) -> Parts<'_> {
        Parts::new(
            self.geodesic.as_ref(),
            (&self.centroid.0, &self.centroid.1, self.features.len()),
            self.sketch.as_ref(),
        )
    }
}

impl Chunk {
    fn len(&self) -> usize {
        self.ids.len()
    }

    /// Writes `row` at `slot`, which is either taken (replaced) or the next free one.
    fn set(&mut self, slot: usize, row: Row) {
        fn put<T>(column: &mut Vec<T>, slot: usize, value: T) {
            if slot == column.len() {
                column.push(value);
            } else {
                column[slot] = value;
            }
        }
        match self.spans.get_mut(slot / BLOCK) {
            Some(span) => span.widen(row.parts()),
            None => self.spans.push(BlockSpan::of(row.parts())),
        }
        self.d2.set(slot, &row.d2);
        self.ecc_mean.set(slot, &row.centroid.0);
        self.d2_mean.set(slot, &row.centroid.1);
        put(&mut self.ids, slot, row.id);
        put(&mut self.features, slot, row.features);
        put(&mut self.light_fields, slot, row.light_field);
        put(&mut self.summaries, slot, row.summary);
        put(&mut self.sketches, slot, row.sketch);
        put(&mut self.lfd, slot, row.lfd);
        put(&mut self.geodesic, slot, row.geodesic);
    }

    fn parts(&self, slot: usize) -> Parts<'_> {
        Parts::new(
            self.geodesic[slot].as_ref(),
            (
                self.ecc_mean.get(slot),
                self.d2_mean.get(slot),
                self.features[slot].len(),
            ),
            self.sketches[slot].as_ref(),
        )
    }

    /// Each block's boxes from its entries alone.
    fn box_blocks(&mut self) {
        let spans = (0..self.len())
            .step_by(BLOCK)
            .map(|first| {
                let mut span = BlockSpan::of(self.parts(first));
                for slot in first + 1..(first + BLOCK).min(self.len()) {
                    span.widen(self.parts(slot));
                }
                span
            })
            .collect();
        self.spans = spans;
    }

    /// Takes the last entry out.
    fn pop(&mut self) -> Row {
        const TAKEN: &str = "a chunk in the index is never empty";
        let centroid = (self.ecc_mean.pop(), self.d2_mean.pop());
        let row = Row {
            centroid,
            d2: self.d2.pop(),
            id: self.ids.pop().expect(TAKEN),
            features: self.features.pop().expect(TAKEN),
            light_field: self.light_fields.pop().expect(TAKEN),
            summary: self.summaries.pop().expect(TAKEN),
            sketch: self.sketches.pop().expect(TAKEN),
            lfd: self.lfd.pop().expect(TAKEN),
            geodesic: self.geodesic.pop().expect(TAKEN),
        };
        // The last block's first entry: the block is empty.
        if self.len().is_multiple_of(BLOCK) {
            self.spans.pop();
        }
        row
    }
}

/// One entry of the index: a chunk and a slot in it.
#[derive(Clone, Copy)]
pub struct Entry<'a> {
    chunk: &'a Chunk,
    slot: usize,
    number: usize,
}

impl<'a> Entry<'a> {
    /// Its number in the index.
    pub fn number(self) -> usize {
        self.number
    }

    pub fn parts(self) -> Parts<'a> {
        self.chunk.parts(self.slot)
    }

    pub fn id(self) -> &'a Arc<str> {
        &self.chunk.ids[self.slot]
    }

    /// The salient features as the ECC method compares them.
    pub fn features(self) -> &'a Features {
        &self.chunk.features[self.slot]
    }

    /// The light field descriptor, for the LFD's exact distance: read from the shelf.
    pub fn light_field(self) -> io::Result<Option<LightFieldDescriptor>> {
        match &self.chunk.light_fields[self.slot] {
            Some(slot) => slot.get(),
            None => Ok(None),
        }
    }

    /// What every method compares, for a distance without bounds, with the light field
    /// descriptor read by the caller if it needs one.
    pub fn compared<'b>(self, lfd: Option<&'b LightFieldDescriptor>) -> Compared<'b>
    where
        'a: 'b,
    {
        Compared {
            features: self.features(),
            d2: self.d2(),
            lfd,
            geodesic: self.geodesic(),
        }
    }

    /// The ECC bound's side ([`Summary`]).
    pub fn summary(self) -> &'a Summary {
        &self.chunk.summaries[self.slot]
    }

    pub fn sketch(self) -> Option<&'a LfdSketch> {
        self.chunk.sketches[self.slot].as_ref()
    }

    pub fn lfd(self) -> Option<&'a LfdSummary> {
        self.chunk.lfd[self.slot].as_ref()
    }

    /// The geodesic descriptor as it is compared.
    pub fn geodesic(self) -> Option<&'a Cumulative> {
        self.chunk.geodesic[self.slot].as_ref()
    }

    /// [`crate::similarity::centroid_bound`]'s side: the feature means and count.
    pub fn centroid(self) -> Centroid<'a> {
        (
            self.chunk.ecc_mean.get(self.slot),
            self.chunk.d2_mean.get(self.slot),
            self.summary().features(),
        )
    }

    /// The global D2 histogram.
    pub fn d2(self) -> &'a [f32] {
        self.chunk.d2.get(self.slot)
    }

    /// Which optional descriptors it holds, from the columns: a pass over every entry should
    /// not read the signature.
    fn held(self) -> Held {
        Held {
            lfd: self.sketch().is_some(),
            geodesic: self.geodesic().is_some(),
        }
    }

    /// [`Method::ranks`] from the columns.
    pub fn ranks(self, method: Method) -> bool {
        method.ranks(self.held())
    }

    /// [`Method::ranks_fully`] from the columns.
    pub fn ranks_fully(self, method: Method) -> bool {
        method.ranks_fully(self.held())
    }
}

/// Every entry, numbered densely from 0 in chunks of [`CHUNK`].
#[derive(Debug, Clone, Default)]
pub struct Columns {
    chunks: Vec<Arc<Chunk>>,
    len: usize,
}

impl Columns {
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn get(&self, i: usize) -> Entry<'_> {
        Entry {
            chunk: &self.chunks[i / CHUNK],
            slot: i % CHUNK,
            number: i,
        }
    }

    /// Appends `row` as entry `len()`.
    pub fn push(&mut self, row: Row) {
        if self.len.is_multiple_of(CHUNK) {
            self.chunks.push(Arc::default());
        }
        let slot = self.len % CHUNK;
        Arc::make_mut(self.chunks.last_mut().expect("a chunk")).set(slot, row);
        self.len += 1;
    }

    /// Replaces entry `i`.
    pub fn set(&mut self, i: usize, row: Row) {
        Arc::make_mut(&mut self.chunks[i / CHUNK]).set(i % CHUNK, row);
    }

    /// Blocks of [`BLOCK`] entries (the last may hold fewer).
    pub fn blocks(&self) -> usize {
        self.len.div_ceil(BLOCK)
    }

    /// What the entries of block `b` hold.
    pub fn span(&self, b: usize) -> &BlockSpan {
        let first = b * BLOCK;
        &self.chunks[first / CHUNK].spans[first % CHUNK / BLOCK]
    }

    /// Puts entry `order[i]` at `i` for every `i` (a permutation), along its cycles one entry
    /// at a time, not through a second copy of the index; then boxes each block anew.
    pub fn permute(&mut self, order: &[usize]) {
        let mut placed = vec![false; order.len()];
        for start in 0..order.len() {
            if placed[start] || order[start] == start {
                continue;
            }
            let first = self.take_row(start);
            let mut at = start;
            loop {
                placed[at] = true;
                let from = order[at];
                if from == start {
                    self.set(at, first);
                    break;
                }
                let row = self.take_row(from);
                self.set(at, row);
                at = from;
            }
        }
        for chunk in &mut self.chunks {
            Arc::make_mut(chunk).box_blocks();
        }
    }

    /// Moves entry `i` out, its heap parts moved and not copied, and leaves a placeholder for
    /// [`Columns::set`] to overwrite.
    fn take_row(&mut self, i: usize) -> Row {
        let (chunk, slot) = (Arc::make_mut(&mut self.chunks[i / CHUNK]), i % CHUNK);
        Row {
            id: chunk.ids[slot].clone(),
            features: std::mem::take(&mut chunk.features[slot]),
            light_field: chunk.light_fields[slot].take(),
            d2: chunk.d2.get(slot).to_vec(),
            summary: std::mem::take(&mut chunk.summaries[slot]),
            centroid: (
                chunk.ecc_mean.get(slot).to_vec(),
                chunk.d2_mean.get(slot).to_vec(),
            ),
            sketch: chunk.sketches[slot].take(),
            lfd: chunk.lfd[slot].take(),
            geodesic: chunk.geodesic[slot].take(),
        }
    }

    /// Takes the last entry out.
    fn pop(&mut self) -> Row {
        let last = Arc::make_mut(self.chunks.last_mut().expect("a chunk")).pop();
        self.len -= 1;
        if self.len.is_multiple_of(CHUNK) {
            self.chunks.pop();
        }
        last
    }

    /// Removes entry `i`, moving the last entry into its place; returns the moved entry's id.
    pub fn swap_remove(&mut self, i: usize) -> Option<Arc<str>> {
        let last = self.pop();
        if i == self.len {
            return None;
        }
        let moved = last.id.clone();
        self.set(i, last);
        Some(moved)
    }

    /// Every entry, in parallel by chunk: each chunk's entries are read in order, from its
    /// contiguous columns.
    pub fn par_entries(&self) -> impl ParallelIterator<Item = Entry<'_>> {
        self.chunks
            .par_iter()
            .enumerate()
            .flat_map_iter(|(c, chunk)| Self::in_chunk(c, chunk))
    }

    /// Every entry, in order.
    pub fn iter(&self) -> impl Iterator<Item = Entry<'_>> {
        self.chunks
            .iter()
            .enumerate()
            .flat_map(|(c, chunk)| Self::in_chunk(c, chunk))
    }

    fn in_chunk(c: usize, chunk: &Chunk) -> impl Iterator<Item = Entry<'_>> {
        (0..chunk.len()).map(move |slot| Entry {
            chunk,
            slot,
            number: c * CHUNK + slot,
        })
    }
}

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
use crate::descriptor::lfd::{LfdSketch, LfdSummary};
use crate::descriptor::{GeodesicDescriptor, LightFieldDescriptor};
use crate::params::{Params, SimilarityParams};
use crate::signature::{Signature, Staleness};
use crate::similarity::{Centroid, Features, Summary};

use super::shelf::Slot;
use super::{Compared, Holds, Method};

/// Entries per chunk: a copy on write moves about a megabyte.
const CHUNK: usize = 1024;

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
    extractions: Vec<Arc<Params>>,
    features: Vec<Features>,
    light_fields: Vec<Option<Arc<Slot>>>,
    summaries: Vec<Summary>,
    sketches: Vec<Option<LfdSketch>>,
    lfd: Vec<Option<LfdSummary>>,
    geodesic: Vec<Option<Cumulative>>,
    d2: Rows,
    ecc_mean: Rows,
    d2_mean: Rows,
}

/// What the index keeps of one model, computed once when it is inserted.
pub struct Row {
    id: Arc<str>,
    extraction: Arc<Params>,
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
    /// `light_field` is `signature.lfd` shelved.
    pub fn new(
        id: Arc<str>,
        signature: &Signature,
        light_field: Option<Arc<Slot>>,
        params: &SimilarityParams,
    ) -> Self {
        let features = Features::of(&signature.features);
        Self {
            centroid: features.centroid(),
            summary: Summary::of(&features, params),
            features,
            sketch: signature.lfd.as_ref().map(|d| d.sketch()),
            lfd: signature.lfd.as_ref().map(|d| d.summary()),
            light_field,
            d2: signature.d2.clone(),
            geodesic: signature
                .geodesic
                .as_ref()
                .map(GeodesicDescriptor::cumulative),
            id,
            extraction: Arc::new(signature.params.clone()),
        }
    }

    /// The parameters it was extracted with, to share with other rows.
    pub fn extraction(&self) -> &Arc<Params> {
        &self.extraction
    }

    /// Shares `extraction`, equal to this row's.
    pub fn share(&mut self, extraction: Arc<Params>) {
        debug_assert!(*extraction == *self.extraction);
        self.extraction = extraction;
    }

    pub fn id(&self) -> &Arc<str> {
        &self.id
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
        self.d2.set(slot, &row.d2);
        self.ecc_mean.set(slot, &row.centroid.0);
        self.d2_mean.set(slot, &row.centroid.1);
        put(&mut self.ids, slot, row.id);
        put(&mut self.extractions, slot, row.extraction);
        put(&mut self.features, slot, row.features);
        put(&mut self.light_fields, slot, row.light_field);
        put(&mut self.summaries, slot, row.summary);
        put(&mut self.sketches, slot, row.sketch);
        put(&mut self.lfd, slot, row.lfd);
        put(&mut self.geodesic, slot, row.geodesic);
    }

    /// Takes the last entry out.
    fn pop(&mut self) -> Row {
        const TAKEN: &str = "a chunk in the index is never empty";
        let centroid = (self.ecc_mean.pop(), self.d2_mean.pop());
        Row {
            centroid,
            d2: self.d2.pop(),
            id: self.ids.pop().expect(TAKEN),
            extraction: self.extractions.pop().expect(TAKEN),
            features: self.features.pop().expect(TAKEN),
            light_field: self.light_fields.pop().expect(TAKEN),
            summary: self.summaries.pop().expect(TAKEN),
            sketch: self.sketches.pop().expect(TAKEN),
            lfd: self.lfd.pop().expect(TAKEN),
            geodesic: self.geodesic.pop().expect(TAKEN),
        }
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

    pub fn id(self) -> &'a Arc<str> {
        &self.chunk.ids[self.slot]
    }

    /// The salient features as the ECC method compares them.
    pub fn features(self) -> &'a Features {
        &self.chunk.features[self.slot]
    }

    /// The light field descriptor, for the LFD's exact distance: read from the shelf.
    pub fn light_field(self) -> io::Result<Option<LightFieldDescriptor>> {
        self.chunk.light_fields[self.slot]
            .as_ref()
            .map(|slot| slot.get())
            .transpose()
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

    /// [`Signature::staleness`] of the entry's signature.
    pub fn staleness(self, current: &Params) -> Option<Staleness> {
        let holds = self.holds();
        Staleness::of(
            &self.chunk.extractions[self.slot],
            holds.lfd && holds.geodesic,
            current,
        )
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
    fn holds(self) -> Holds {
        Holds {
            lfd: self.sketch().is_some(),
            geodesic: self.geodesic().is_some(),
        }
    }

    /// [`Method::comparable`] from the columns.
    pub fn comparable(self, method: Method) -> bool {
        method.compares(self.holds())
    }

    /// [`Method::complete`] from the columns.
    pub fn complete(self, method: Method) -> bool {
        method.completes(self.holds())
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

    /// Removes entry `i`, moving the last entry into its place; returns the moved entry's id.
    pub fn swap_remove(&mut self, i: usize) -> Option<Arc<str>> {
        let last = Arc::make_mut(self.chunks.last_mut().expect("a chunk")).pop();
        self.len -= 1;
        if self.len.is_multiple_of(CHUNK) {
            self.chunks.pop();
        }
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

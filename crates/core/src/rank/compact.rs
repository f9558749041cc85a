//! A model as an index ranks it, without its light field descriptor: what a first stage in a
//! database keeps beside each model's vector and returns for each of its candidates (#40).
//!
//! The descriptor is most of a signature (4.5 KB packed; a real signature is ~5.2 KB
//! compressed), yet a ranking of a thousand candidates reads it for the few its bounds leave
//! (34–296 at 10 000 models in the load bench): the summary (900 bytes) gives those bounds, and
//! the descriptors come in a second round trip ([`super::Index::away`]).
//!
//! The form holds the compared parts in the form the index compares them ([`Features`]'
//! rows, the quantised histograms), uncompressed (1.9 KB): a ranking reads a thousand of
//! these, and a row from one costs 5.9 µs, where decoding a signature's compressed sections,
//! its parameters (JSON) and its features one allocation each costs 29 µs (`benches/rank.rs`,
//! the load bench's base models). It leaves out the extraction parameters: whether a model
//! is stale is the service's to know, from the stored signature.

use serde::{Deserialize, Serialize};

use crate::descriptor::geodesic::Cumulative;
use crate::descriptor::lfd::LfdSummary;
use crate::descriptor::GeodesicDescriptor;
use crate::signature::{dequantise, quantise, Signature};
use crate::similarity::Features;
use crate::{Error, Result};

/// The stored form (postcard).
#[derive(Serialize, Deserialize)]
struct Stored {
    features: u32,
    /// [`Features::rows`]: the ECC rows, then the region D2 bins' rows.
    ecc: Vec<f32>,
    bins: Vec<u16>,
    /// The model's D2 histogram, quantised as a signature stores it.
    d2: Vec<u16>,
    /// The geodesic descriptor's two histograms, quantised.
    geodesic: Option<(Vec<u16>, Vec<u16>)>,
    /// [`LfdSummary::sums`].
    lfd: Option<Vec<u16>>,
}

/// What a row of the index is made of ([`super::Row::compact`]), read from [`of`]'s bytes.
pub(crate) struct Compact {
    pub features: Features,
    pub d2: Vec<f32>,
    pub geodesic: Option<Cumulative>,
    pub lfd: Option<LfdSummary>,
}

/// The compact form of `signature`. Its histograms are quantised as a stored signature's are:
/// of a signature read from its bytes, rows from this form equal rows from the signature.
pub fn of(signature: &Signature) -> Vec<u8> {
    let features = Features::of(&signature.features);
    let (count, ecc, bins) = features.rows();
    let stored = Stored {
        features: count as u32,
        ecc: ecc.to_vec(),
        bins: bins.to_vec(),
        d2: quantise(&signature.d2),
        geodesic: (signature.geodesic.as_ref())
            .map(|g| (quantise(&g.distances), quantise(&g.eccentricity))),
        lfd: signature.lfd.as_ref().map(|d| d.summary().sums()),
    };
    postcard::to_stdvec(&stored).expect("serialising to memory cannot fail")
}

/// The parts of a row, from [`of`]'s bytes.
pub(crate) fn read(bytes: &[u8]) -> Result<Compact> {
    let corrupt = |message: &str| Error::CorruptSignature {
        message: format!("compact form: {message}"),
    };
    let stored: Stored = postcard::from_bytes(bytes).map_err(|_| corrupt("not readable"))?;
    let features = Features::from_rows(stored.features as usize, stored.ecc, stored.bins)
        .ok_or_else(|| corrupt("feature rows"))?;
    let geodesic = stored.geodesic.map(|(distances, eccentricity)| {
        GeodesicDescriptor {
            distances: dequantise(&distances),
            eccentricity: dequantise(&eccentricity),
        }
        .cumulative()
    });
    let lfd = stored
        .lfd
        .map(|sums| LfdSummary::from_sums(&sums).ok_or_else(|| corrupt("light field sums")))
        .transpose()?;
    Ok(Compact {
        features,
        d2: dequantise(&stored.d2),
        geodesic,
        lfd,
    })
}

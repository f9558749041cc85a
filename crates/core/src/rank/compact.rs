//! A model as an index ranks it, without its light field descriptor: what a first stage in a
//! database keeps beside each model's vector and returns for each of its candidates (#40).
//!
//! The descriptor is most of a signature (4.5 KB packed; a real signature is ~5.2 KB
//! compressed, its compact form ~2.2 KB), yet a ranking of a thousand candidates reads it for
//! the few its bounds leave (34–296 at 10 000 models in the load bench): the summary (900
//! bytes) gives those bounds, and the descriptors come in a second round trip
//! ([`super::Index::away`]).

use serde::{Deserialize, Serialize};

use crate::descriptor::lfd::LfdSummary;
use crate::signature::{Signature, SignatureStats};
use crate::{Error, Result};

/// The stored form: the signature without its descriptor or statistics, and the
/// descriptor's [`LfdSummary`] (its sums, unpadded).
#[derive(Serialize, Deserialize)]
struct Stored {
    #[serde(with = "serde_bytes")]
    signature: Vec<u8>,
    lfd: Option<Vec<u16>>,
}

/// The compact form of `signature`.
pub fn of(signature: &Signature) -> Vec<u8> {
    let ranked = Signature {
        lfd: None,
        stats: SignatureStats::default(),
        ..signature.clone()
    };
    let stored = Stored {
        signature: ranked.to_bytes(),
        lfd: signature.lfd.as_ref().map(|d| d.summary().sums()),
    };
    postcard::to_stdvec(&stored).expect("serialising to memory cannot fail")
}

/// The signature without its descriptor and the descriptor's summary, from [`of`]'s bytes.
pub fn read(bytes: &[u8]) -> Result<(Signature, Option<LfdSummary>)> {
    let corrupt = |message: &str| Error::CorruptSignature {
        message: format!("compact form: {message}"),
    };
    let stored: Stored = postcard::from_bytes(bytes).map_err(|_| corrupt("not readable"))?;
    let signature = Signature::from_bytes(&stored.signature)?;
    let lfd = stored
        .lfd
        .map(|sums| LfdSummary::from_sums(&sums).ok_or_else(|| corrupt("light field sums")))
        .transpose()?;
    Ok((signature, lfd))
}

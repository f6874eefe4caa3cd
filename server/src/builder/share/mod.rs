//! Reading only a share of the input: what a part of a distributed build reads
//! ([`footprint`]: its subtrees' windows and the coarse corners beyond them) and the
//! reading itself (`read`: into a sparse spool, or why the share cannot stand
//! alone). `build --update` reads its changed area the same way.

pub mod footprint;
pub(crate) mod read;

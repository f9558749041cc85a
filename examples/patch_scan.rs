// THROWAWAY (not committed): the partial search's patch scan over a 100 000-model store.
use salient::descriptor::patch::Packed;
use salient::store::{Derived, SledStore, Store};
use std::time::Instant;
fn main() {
    let dir = std::env::args().nth(1).unwrap();
    let meshes = std::env::args().nth(2).unwrap();
    let store = SledStore::open(std::path::Path::new(&dir)).unwrap();
    let params = salient::Params::default();
    let limits = salient::params::Limits::default();
    let files = salient::collection::find_meshes(std::path::Path::new(&meshes)).unwrap();
    let packed: Vec<Packed> = files
        .iter()
        .take(60)
        .map(|f| {
            let raw = salient::mesh::load_path(f, &limits).unwrap();
            salient::partial::stored_patches(&raw, &params.mesh).unwrap()
        })
        .collect();
    let query = Packed::piece(&[0.05f32; 27]);
    if store.all_derived(Derived::Patches).next().is_none() {
        let clock = Instant::now();
        let mut after: Option<String> = None;
        let mut n = 0;
        loop {
            let page = store.list(after.as_deref(), 1000).unwrap();
            if page.is_empty() {
                break;
            }
            for r in &page {
                store
                    .put_derived(
                        Derived::Patches,
                        r.id.as_str(),
                        &r.content_hash,
                        &packed[n % packed.len()].to_bytes(),
                    )
                    .unwrap();
                n += 1;
            }
            after = Some(page.last().unwrap().id.to_string());
        }
        println!("filled {n} in {:.1} s", clock.elapsed().as_secs_f64());
    }
    for _ in 0..5 {
        let clock = Instant::now();
        let mut nearest = Vec::new();
        for entry in store.all_derived(Derived::Patches) {
            let (id, bytes) = entry.unwrap();
            if let Some(p) = Packed::from_bytes(&bytes) {
                nearest.push((p.nearest(&query), id.to_string()));
            }
        }
        nearest.sort_by(|a, b| a.0.total_cmp(&b.0).then_with(|| a.1.cmp(&b.1)));
        println!(
            "scan of {} in {:.0} ms",
            nearest.len(),
            clock.elapsed().as_secs_f64() * 1e3
        );
    }
}

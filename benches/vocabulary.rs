//! Vocabulary load time for 100k words (k = 10, L = 5: 111,111 nodes) from the binary format,
//! and the bag-of-words transform of 1000 descriptors.

use criterion::{criterion_group, criterion_main, Criterion};
use sdslam::place_recognition::{decode_vocabulary, encode_vocabulary, Node, Vocabulary};

fn vocabulary(c: &mut Criterion) {
    let mut s = 1u64;
    let mut rnd = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        s
    };
    // A full 10-ary tree of depth 5 with random descriptors.
    let mut nodes = vec![Node {
        parent: 0,
        children: Vec::new(),
        descriptor: [0; 4],
        weight: 0.0,
        word: None,
    }];
    let mut level = vec![0u32];
    for _ in 0..5 {
        let mut next = Vec::new();
        for &p in &level {
            for _ in 0..10 {
                let id = nodes.len() as u32;
                nodes.push(Node {
                    parent: p,
                    children: Vec::new(),
                    descriptor: [rnd(), rnd(), rnd(), rnd()],
                    weight: 1.0,
                    word: None,
                });
                nodes[p as usize].children.push(id);
                next.push(id);
            }
        }
        level = next;
    }
    let mut words = Vec::new();
    for &l in &level {
        nodes[l as usize].word = Some(words.len() as u32);
        words.push(l);
    }
    let v = Vocabulary {
        k: 10,
        levels: 5,
        nodes,
        words,
    };
    let bytes = encode_vocabulary(&v);
    let mut g = c.benchmark_group("vocabulary");
    g.sample_size(20);
    g.bench_function("decode_100k_words", |b| {
        b.iter(|| decode_vocabulary(&bytes).expect("decode"))
    });
    let ds: Vec<[u64; 4]> = (0..1000).map(|_| [rnd(), rnd(), rnd(), rnd()]).collect();
    g.bench_function("transform_1000_descriptors_100k_words", |b| {
        b.iter(|| v.transform(&ds, 2))
    });
    g.finish();
}

criterion_group!(benches, vocabulary);
criterion_main!(benches);

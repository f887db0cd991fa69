//! The one seeded random-number generator of the workspace, here in the lowest crate so
//! every crate can use it: SplitMix64 (Steele, Lea & Flood) for short sequences (sample
//! data, shuffles, test inputs) and seeding, and xoshiro256++ (Blackman & Vigna) for the
//! renderers' Monte Carlo, with independent streams per work item (`Rng::stream(seed,
//! index)`) so that multi-threaded work gives the same result for a seed on any thread
//! count. Not for cryptography.

/// SplitMix64: one 64-bit word of state; every seed is fine.
#[derive(Debug, Clone)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        unit_interval(self.next_u64())
    }
    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }
    /// Uniform in 0..n (n > 0; the modulo bias is below 2⁻³² for n < 2³²).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
}

/// The top 53 bits of `x` as a float in [0, 1).
fn unit_interval(x: u64) -> f64 {
    (x >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// xoshiro256++: 256 bits of state, seeded through SplitMix64.
#[derive(Debug, Clone)]
pub struct Rng {
    s: [u64; 4],
}

impl Rng {
    pub fn new(seed: u64) -> Rng {
        let mut x = SplitMix64(seed);
        Rng { s: [x.next_u64(), x.next_u64(), x.next_u64(), x.next_u64()] }
    }

    /// The generator for work item `index` of a run seeded with `seed`.
    pub fn stream(seed: u64, index: u64) -> Rng {
        Rng::new(SplitMix64(seed ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03)).next_u64())
    }

    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let out = (s[0].wrapping_add(s[3])).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        out
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        unit_interval(self.next_u64())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_generators_give_their_published_sequences() {
        // SplitMix64 from seed 1234567 (the reference implementation's first outputs).
        let mut s = SplitMix64(1234567);
        assert_eq!([s.next_u64(), s.next_u64(), s.next_u64()], [6457827717110365317, 3203168211198807973, 9817491932198370423]);
        // xoshiro256++ from the state [1, 2, 3, 4] (as rand_xoshiro's test); streams differ.
        let mut r = Rng { s: [1, 2, 3, 4] };
        let first: Vec<u64> = (0..5).map(|_| r.next_u64()).collect();
        assert_eq!(first, [41943041, 58720359, 3588806011781223, 3591011842654386, 9228616714210784205]);
        assert_ne!(Rng::stream(1, 0).next_u64(), Rng::stream(1, 1).next_u64());
        let mut u = Rng::new(7);
        assert!((0..10_000).map(|_| u.uniform()).all(|x| (0.0..1.0).contains(&x)));
    }
}

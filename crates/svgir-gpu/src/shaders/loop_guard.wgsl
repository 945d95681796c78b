// Whether this invocation's loops were cut short. Mesa's llvmpipe (lavapipe) caps the loop
// iterations of one invocation at 65535, all loops of the shader together (its gallivm loop
// limiter), and past the cap leaves every loop at its next test without a word: a tile list or
// a ray march that long returns part of its sums. Run after the kernel's loops, a loop of two
// iterations whose count the compiler cannot fold (`status[1]` stays 0) then runs once, and the
// kernel's bit goes into `status[0]`, which the host reads (`Gpu::check`). Hardware GPUs have no
// such cap: the loop runs twice and nothing is written. The kernel binds `status`.

fn guard_loops(bit: u32) {
    let two = 2u + atomicLoad(&status[1]);
    var k = 0u;
    for (var i = 0u; i < two; i++) {
        k += 1u;
    }
    if k != two {
        atomicOr(&status[0], bit);
    }
}

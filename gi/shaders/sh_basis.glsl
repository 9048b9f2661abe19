// Real orthonormal SH, bands 0..3, in glTF world coordinates (y up, no
// Condon-Shortley phase): the table of gi/sh/sh_basis.h. y[k] holds
// coefficients 4k .. 4k+3, as the _SH_TRANSFER_k vertex attributes do.
#ifndef LF_SH_BASIS_GLSL
#define LF_SH_BASIS_GLSL

void sh_evaluate(vec3 d, out vec4 y[4]) {
    float x = d.x, yy = d.y, z = d.z;
    y[0] = vec4(0.28209479177387814, 0.4886025119029199 * x, 0.4886025119029199 * yy, 0.4886025119029199 * z);
    y[1] = vec4(1.0925484305920792 * z * x, 1.0925484305920792 * x * yy,
                0.31539156525252005 * (3.0 * yy * yy - 1.0), 1.0925484305920792 * z * yy);
    y[2] = vec4(0.5462742152960396 * (z * z - x * x), 0.5900435899266435 * x * (3.0 * z * z - x * x),
                2.890611442640554 * x * yy * z, 0.4570457994644658 * x * (5.0 * yy * yy - 1.0));
    y[3] = vec4(0.3731763325901154 * yy * (5.0 * yy * yy - 3.0), 0.4570457994644658 * z * (5.0 * yy * yy - 1.0),
                1.445305721320277 * yy * (z * z - x * x), 0.5900435899266435 * z * (z * z - 3.0 * x * x));
}

#endif

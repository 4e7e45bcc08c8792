// The FCL peer of `fracnav bench collision` (see bench.h): one fragment as an octomap octree or as
// an OBBRSS mesh BVH of its exposed voxel faces, and FCL's boolean collision between two of them.
extern "C" {
#include "bench.h"
#include "err.h"
}

#include <fcl/geometry/bvh/BVH_model.h>
#include <fcl/geometry/octree/octree.h>
#include <fcl/math/bv/OBBRSS.h>
#include <fcl/narrowphase/collision.h>
#include <octomap/octomap.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <new>
#include <vector>

struct bench_fcl {
    std::shared_ptr<fcl::CollisionGeometryd> geom;
    size_t size;
};

namespace {

struct grid {
    const frag *f;
    uint8_t lut[256];
    grid(const frag *fr, const obb_params *p) : f(fr)
    {
        for (int v = 0; v < 256; v++)
            lut[v] = obb_effective_prob((uint8_t)v, p);
    }
    bool bone(int i, int j, int k) const
    {
        if (i < 0 || j < 0 || k < 0 || i >= f->dim[0] || j >= f->dim[1] || k >= f->dim[2])
            return false;
        return lut[f->prob[((size_t)k * f->dim[1] + j) * f->dim[0] + i]] != 0;
    }
};

fcl::Transform3d transform(const pose *p)
{
    fcl::Transform3d t = fcl::Transform3d::Identity();
    t.linear() = Eigen::Quaterniond(p->q[0], p->q[1], p->q[2], p->q[3]).toRotationMatrix();
    t.translation() = Eigen::Vector3d(p->t[0], p->t[1], p->t[2]);
    return t;
}

// Each voxel box filled with octree cells at the finest spacing (centres inside the box).
bench_fcl *octree(const frag *f, const obb_params *p)
{
    grid g(f, p);
    const double *s = f->spacing;
    double res = std::min(s[0], std::min(s[1], s[2]));
    auto tree = std::make_shared<octomap::OcTree>(res);
    int sub[3];
    for (int a = 0; a < 3; a++)
        sub[a] = std::max(1, (int)std::ceil(s[a] / res - 1e-9));
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++)
            for (int i = 0; i < f->dim[0]; i++) {
                if (!g.bone(i, j, k))
                    continue;
                int c[3] = {i, j, k};
                for (int w = 0; w < sub[2]; w++)
                    for (int v = 0; v < sub[1]; v++)
                        for (int u = 0; u < sub[0]; u++) {
                            int uvw[3] = {u, v, w};
                            float x[3];
                            for (int a = 0; a < 3; a++)
                                x[a] = (float)(c[a] * s[a] - s[a] / 2 + (uvw[a] + 0.5) * s[a] / sub[a]);
                            tree->updateNode(octomap::point3d(x[0], x[1], x[2]), true, true);
                        }
            }
    tree->updateInnerOccupancy();
    auto *out = new bench_fcl;
    out->size = tree->getNumLeafNodes();
    out->geom = std::make_shared<fcl::OcTreed>(tree);
    return out;
}

// Two triangles per voxel face between bone and not-bone.
bench_fcl *mesh(const frag *f, const obb_params *p)
{
    grid g(f, p);
    const double *s = f->spacing;
    std::vector<fcl::Vector3d> verts;
    std::vector<fcl::Triangle> tris;
    static const int nb[6][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++)
            for (int i = 0; i < f->dim[0]; i++) {
                if (!g.bone(i, j, k))
                    continue;
                for (int n = 0; n < 6; n++) {
                    if (g.bone(i + nb[n][0], j + nb[n][1], k + nb[n][2]))
                        continue;
                    int ax = n / 2, u = (ax + 1) % 3, v = (ax + 2) % 3;
                    double c[3] = {i * s[0], j * s[1], k * s[2]};
                    c[ax] += (n % 2 ? 0.5 : -0.5) * s[ax];
                    size_t base = verts.size();
                    for (int q = 0; q < 4; q++) {
                        fcl::Vector3d x(c[0], c[1], c[2]);
                        x[u] += ((q & 1) ? 0.5 : -0.5) * s[u];
                        x[v] += ((q & 2) ? 0.5 : -0.5) * s[v];
                        verts.push_back(x);
                    }
                    tris.emplace_back(base, base + 1, base + 3);
                    tris.emplace_back(base, base + 3, base + 2);
                }
            }
    auto model = std::make_shared<fcl::BVHModel<fcl::OBBRSSd>>();
    model->beginModel((int)tris.size(), (int)verts.size());
    model->addSubModel(verts, tris);
    model->endModel();
    auto *out = new bench_fcl;
    out->size = tris.size();
    out->geom = model;
    return out;
}

} // namespace

extern "C" bench_fcl *bench_fcl_octree(const frag *f, const obb_params *p)
{
    try {
        return octree(f, p);
    } catch (const std::exception &e) {
        fn_err_set(FN_ENOMEM, "FCL octree of '%s': %s", f->name, e.what());
        return nullptr;
    }
}

extern "C" bench_fcl *bench_fcl_mesh(const frag *f, const obb_params *p)
{
    try {
        return mesh(f, p);
    } catch (const std::exception &e) {
        fn_err_set(FN_ENOMEM, "FCL mesh of '%s': %s", f->name, e.what());
        return nullptr;
    }
}

extern "C" size_t bench_fcl_size(const bench_fcl *g)
{
    return g ? g->size : 0;
}

extern "C" int bench_fcl_collide(const bench_fcl *a, const pose *aw, const bench_fcl *b,
                                 const pose *bw)
{
    if (!a || !b || !aw || !bw)
        return fn_err_set(FN_EINVAL, "bench_fcl_collide: missing geometry or pose");
    fcl::CollisionRequestd req;
    fcl::CollisionResultd res;
    fcl::collide(a->geom.get(), transform(aw), b->geom.get(), transform(bw), req, res);
    return res.isCollision() ? 1 : 0;
}

extern "C" void bench_fcl_free(bench_fcl *g)
{
    delete g;
}

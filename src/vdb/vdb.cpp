/* drench vdb: the extern "C" shim over OpenVDB 10 (the only C++ translation unit in drench).
 *
 * Every entry point runs its body inside try/catch and turns any exception into a DrStatus
 * (translate_exception), so no C++ exception reaches C callers. OpenVDB is initialised once with
 * std::call_once. */

#include "vdb/vdb.h" /* includes core/core.h with C linkage */

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <mutex>
#include <new>
#include <string>
#include <utility>
#include <vector>

#include <unistd.h>

#include <openvdb/Exceptions.h>
#include <openvdb/openvdb.h>
#include <openvdb/io/File.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/LevelSetFilter.h>
#include <openvdb/tools/LevelSetMeasure.h>
#include <openvdb/tools/LevelSetRebuild.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/ParticlesToLevelSet.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <openvdb/tree/LeafManager.h>

struct DrVdbSurface {
    openvdb::FloatGrid::Ptr surface;
    openvdb::Vec3SGrid::Ptr vel;
    double adaptivity;
};

namespace {

/* Narrow-band half-width of the liquid level set in voxels (DESIGN §4). */
constexpr float kSurfaceHalfWidth = 3.0f;
/* Half-width used while rasterising particles: one voxel wider than the final band so that every
 * voxel of the rebuilt band lies inside some particle's rasterised band and so has a transferred
 * velocity (smoothing moves the zero crossing by a fraction of a voxel per pass). */
constexpr double kRasterHalfWidth = 4.0;
/* ParticlesToLevelSet's smallest resolvable sphere radius (its Nyquist limit), in voxels. */
constexpr double kMinRadiusVoxels = 1.5;
/* ParticlesToLevelSet ignores spheres above its Rmax (100 voxels by default); such spheres cost
 * (R + w)^3 voxels each, so they are refused as input instead. */
constexpr double kMaxRadiusVoxels = 100.0;
/* Index coordinates are int32; positions are kept well inside that range. */
constexpr double kMaxIndexCoord = 1073741824.0; /* 2^30 */

std::once_flag g_init_once;

void ensure_init() { std::call_once(g_init_once, [] { openvdb::initialize(); }); }

/* Converts the exception being handled into a status and message. Must be called from a catch
 * block. `op` names the operation, `path` the file concerned (or NULL). */
DrStatus translate_exception(const char *op, const char *path, DrError *err) noexcept
{
    try {
        throw;
    } catch (const std::bad_alloc &) {
        return dr_error_set(err, DR_ERR_NOMEM, path, 0, 0,
                            "%s: out of memory; use a larger voxel size or fewer particles", op);
    } catch (const openvdb::IoError &e) {
        if (path)
            return dr_error_set(err, DR_ERR_IO, path, 0, 0, "%s %s: %s", op, path, e.what());
        return dr_error_set(err, DR_ERR_IO, NULL, 0, 0, "%s: %s", op, e.what());
    } catch (const openvdb::ValueError &e) {
        return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "%s: invalid value: %s", op, e.what());
    } catch (const std::exception &e) {
        return dr_error_set(err, DR_ERR_RUNTIME, path, 0, 0, "%s: OpenVDB failed: %s", op, e.what());
    } catch (...) {
        return dr_error_set(err, DR_ERR_RUNTIME, path, 0, 0, "%s: OpenVDB failed with an unknown exception",
                            op);
    }
}

/* Uniform voxels of size dx, zero translation: voxel (i,j,k) is centred at dx*(i,j,k). */
openvdb::math::Transform::Ptr uniform_transform(double dx)
{
    return openvdb::math::Transform::createLinearTransform(dx);
}

/* ---- mesh -> SDF ---------------------------------------------------------------------------- */

/* MeshToVolume's MeshDataAdapter over a DrTriMesh, giving index-space points in double. */
struct TriMeshAdapter {
    const DrTriMesh *mesh;
    double dx;
    size_t polygonCount() const { return static_cast<size_t>(mesh->nt); }
    size_t pointCount() const { return static_cast<size_t>(mesh->nv); }
    size_t vertexCount(size_t) const { return 3; }
    void getIndexSpacePoint(size_t n, size_t v, openvdb::Vec3d &pos) const
    {
        const double *p = mesh->v + 3 * static_cast<size_t>(mesh->tri[3 * n + v]);
        pos = openvdb::Vec3d(p[0] / dx, p[1] / dx, p[2] / dx);
    }
};

/* Number of undirected edges not shared by exactly two triangles of opposite orientation. */
long count_open_edges(const DrTriMesh *m)
{
    std::vector<std::pair<uint64_t, int>> e;
    e.reserve(3 * static_cast<size_t>(m->nt));
    for (int t = 0; t < m->nt; t++)
        for (int k = 0; k < 3; k++) {
            const uint64_t a = static_cast<uint64_t>(m->tri[3 * t + k]);
            const uint64_t b = static_cast<uint64_t>(m->tri[3 * t + (k + 1) % 3]);
            const uint64_t lo = std::min(a, b), hi = std::max(a, b);
            e.emplace_back(lo * static_cast<uint64_t>(m->nv) + hi, a < b ? 1 : -1);
        }
    std::sort(e.begin(), e.end());
    long open = 0;
    for (size_t i = 0; i < e.size();) {
        size_t j = i;
        int orient = 0;
        while (j < e.size() && e[j].first == e[i].first) orient += e[j++].second;
        if (j - i != 2 || orient != 0) open++;
        i = j;
    }
    return open;
}

DrStatus validate_mesh(const DrTriMesh *mesh, DrError *err)
{
    if (mesh->nv <= 0 || mesh->nt <= 0 || !mesh->v || !mesh->tri)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "collider mesh is empty (%d vertices, %d triangles); give a closed "
                            "triangle mesh",
                            mesh->nv, mesh->nt);
    for (long i = 0; i < 3L * mesh->nv; i++)
        if (!std::isfinite(mesh->v[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "collider mesh vertex %ld has a non-finite coordinate; fix the asset",
                                i / 3);
    for (long i = 0; i < 3L * mesh->nt; i++)
        if (mesh->tri[i] < 0 || mesh->tri[i] >= mesh->nv)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "collider mesh triangle %ld refers to vertex %d, outside [0, %d); fix "
                                "the asset",
                                i / 3, mesh->tri[i], mesh->nv);
    return DR_OK;
}

/* ---- particles -> level set ------------------------------------------------------------------ */

/* ParticlesToLevelSet's ParticleList over flat arrays; the attribute is the velocity. */
struct ParticleList {
    using PosType = openvdb::Vec3R;
    const double *pos;
    const double *vel; /* may be NULL */
    size_t n;
    double radius;
    size_t size() const { return n; }
    void getPos(size_t i, openvdb::Vec3R &p) const
    {
        p = openvdb::Vec3R(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]);
    }
    void getPosRad(size_t i, openvdb::Vec3R &p, openvdb::Real &r) const
    {
        getPos(i, p);
        r = radius;
    }
    void getAtt(size_t i, openvdb::Vec3s &a) const
    {
        if (vel)
            a = openvdb::Vec3s(static_cast<float>(vel[3 * i]), static_cast<float>(vel[3 * i + 1]),
                               static_cast<float>(vel[3 * i + 2]));
        else
            a = openvdb::Vec3s(0.0f, 0.0f, 0.0f);
    }
};

DrStatus validate_desc(const DrVdbSurfaceDesc *d, DrError *err)
{
    if (!(std::isfinite(d->voxel_size) && d->voxel_size > 0.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "surface voxel_size is %g m; it must be finite and > 0 (e.g. 0.004)",
                            d->voxel_size);
    if (!(std::isfinite(d->radius) && d->radius > 0.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "surface particle radius is %g m; it must be finite and > 0 (e.g. 1.5 "
                            "voxels)",
                            d->radius);
    if (d->radius / d->voxel_size > kMaxRadiusVoxels)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "surface particle radius %g m is %.0f voxels; at most %.0f voxels are "
                            "supported: use a larger voxel size or a smaller radius",
                            d->radius, d->radius / d->voxel_size, kMaxRadiusVoxels);
    if (d->smoothing < 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "surface smoothing is %d; it must be >= 0 (passes of curvature flow)",
                            d->smoothing);
    if (!(d->adaptivity >= 0.0 && d->adaptivity <= 1.0))
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "surface adaptivity is %g; it must lie in [0, 1]", d->adaptivity);
    return DR_OK;
}

DrStatus validate_particles(const double *pos, const double *vel, long n, double dx, DrError *err)
{
    if (n < 0)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0, "particle count is %ld; it must be >= 0", n);
    if (n > 0 && !pos)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "%ld particles but no positions were given", n);
    if (static_cast<unsigned long>(n) > std::numeric_limits<openvdb::Index32>::max())
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "%ld particles exceed OpenVDB's 32-bit particle indices; mesh fewer "
                            "particles per call",
                            n);
    for (long i = 0; i < 3 * n; i++) {
        if (!std::isfinite(pos[i]) || std::fabs(pos[i] / dx) > kMaxIndexCoord)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "particle %ld has position component %g m, which is not finite or "
                                "lies beyond 2^30 voxels; remove escaped particles or use a larger "
                                "voxel size",
                                i / 3, pos[i]);
        if (vel && !std::isfinite(vel[i]))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "particle %ld has a non-finite velocity component", i / 3);
    }
    return DR_OK;
}

/* Fills vel (topology = surface's active voxels) from the attribute grid of the rasteriser: the
 * closest particle's velocity. A band voxel the rasterised bands did not reach (possible only
 * where smoothing moved the surface outward by more than the extra raster voxel) takes the value
 * of the nearest attributed voxel within two voxels; the count of those left at zero is logged. */
openvdb::Vec3SGrid::Ptr transfer_velocity(const openvdb::FloatGrid &surface,
                                          const openvdb::Vec3SGrid &att)
{
    using openvdb::Coord;
    using openvdb::Vec3s;
    openvdb::Vec3STree::Ptr tree(
        new openvdb::Vec3STree(surface.tree(), Vec3s(0.0f, 0.0f, 0.0f), openvdb::TopologyCopy()));
    std::atomic<long> unset(0);
    openvdb::tree::LeafManager<openvdb::Vec3STree> leaves(*tree);
    leaves.foreach([&](openvdb::Vec3STree::LeafNodeType &leaf, size_t) {
        auto acc = att.getConstAccessor();
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const Coord c = it.getCoord();
            Vec3s v;
            if (acc.probeValue(c, v)) {
                it.setValue(v);
                continue;
            }
            int best = std::numeric_limits<int>::max();
            Vec3s best_v(0.0f, 0.0f, 0.0f);
            for (int dk = -2; dk <= 2; dk++)
                for (int dj = -2; dj <= 2; dj++)
                    for (int di = -2; di <= 2; di++) {
                        const int d2 = di * di + dj * dj + dk * dk;
                        if (d2 >= best) continue;
                        if (acc.probeValue(c.offsetBy(di, dj, dk), v)) {
                            best = d2;
                            best_v = v;
                        }
                    }
            if (best == std::numeric_limits<int>::max()) unset++;
            it.setValue(best_v);
        }
    });
    if (unset.load() > 0)
        dr_log_debug("vdb: %ld band voxels had no particle within reach; their velocity is zero",
                     unset.load());
    openvdb::Vec3SGrid::Ptr vel = openvdb::Vec3SGrid::create(tree);
    vel->setTransform(surface.transform().copy());
    return vel;
}

void name_grids(DrVdbSurface *s)
{
    s->surface->setName("surface");
    s->surface->setGridClass(openvdb::GRID_LEVEL_SET);
    s->vel->setName("vel");
    s->vel->setGridClass(openvdb::GRID_UNKNOWN);
    s->vel->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
    s->vel->setIsInWorldSpace(true);
}

/* Writes `text` into buf[size]; DR_ERR_INPUT if it does not fit. */
DrStatus copy_out(const std::string &text, char *buf, size_t size, const char *what, DrError *err)
{
    if (text.size() + 1 > size)
        return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                            "%s needs %zu bytes but the buffer holds %zu; pass a larger buffer", what,
                            text.size() + 1, size);
    std::memcpy(buf, text.c_str(), text.size() + 1);
    return DR_OK;
}

} /* namespace */

/* ---- public API --------------------------------------------------------------------------- */

extern "C" DrStatus dr_vdb_init(DrError *err)
{
    try {
        ensure_init();
        return DR_OK;
    } catch (...) {
        return translate_exception("initialising OpenVDB", NULL, err);
    }
}

extern "C" DrStatus dr_vdb_mesh_to_sdf(const DrTriMesh *mesh, double dx, int pad_voxels,
                                       DrDenseSdf *out, DrError *err)
{
    assert(mesh && out);
    float *phi = nullptr;
    try {
        ensure_init();
        DR_TRY(validate_mesh(mesh, err));
        if (!(std::isfinite(dx) && dx > 0.0))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "SDF voxel size is %g m; it must be finite and > 0", dx);
        if (pad_voxels < 0)
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "SDF padding is %d voxels; it must be >= 0", pad_voxels);

        /* 1. node box: mesh bounds snapped outward to multiples of dx, plus the padding */
        DrVec3 lo, hi;
        (void)dr_trimesh_bounds(mesh, &lo, &hi);
        double ilo[3], ihi[3];
        for (int a = 0; a < 3; a++) {
            ilo[a] = std::floor(dr_v3_get(lo, a) / dx) - pad_voxels;
            ihi[a] = std::ceil(dr_v3_get(hi, a) / dx) + pad_voxels;
            if (std::fabs(ilo[a]) > kMaxIndexCoord || std::fabs(ihi[a]) > kMaxIndexCoord)
                return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                    "collider mesh lies %g voxels from the origin; use a larger "
                                    "voxel size or move the mesh nearer the origin",
                                    std::max(std::fabs(ilo[a]), std::fabs(ihi[a])));
        }
        const double nxd = ihi[0] - ilo[0] + 1, nyd = ihi[1] - ilo[1] + 1, nzd = ihi[2] - ilo[2] + 1;
        if (nxd * nyd * nzd > static_cast<double>(DR_VDB_SDF_MAX_NODES))
            return dr_error_set(err, DR_ERR_INPUT, NULL, 0, 0,
                                "collider SDF grid would be %.0f x %.0f x %.0f nodes, more than "
                                "512^3; use a larger voxel size (now %g m)",
                                nxd, nyd, nzd, dx);
        const int nx = static_cast<int>(nxd), ny = static_cast<int>(nyd), nz = static_cast<int>(nzd);

        const long open = count_open_edges(mesh);
        if (open > 0)
            dr_log_warn("collider mesh is not closed: %ld open edges; inside/outside may be wrong "
                        "behind holes wider than a voxel",
                        open);

        /* 2. sparse SDF: exact distances in the whole interior (interior band = FLT_MAX), a band of
         *    max(3, pad + 1) voxels outside; signedFloodFill inside meshToVolume gives the tiles
         *    beyond the band their sign. */
        const float ex_band = static_cast<float>(std::max(3, pad_voxels + 1));
        openvdb::math::Transform::Ptr xform = uniform_transform(dx);
        TriMeshAdapter adapter{mesh, dx};
        openvdb::FloatGrid::Ptr grid = openvdb::tools::meshToVolume<openvdb::FloatGrid>(
            adapter, *xform, ex_band, std::numeric_limits<float>::max());

        /* 3. sample every node into the caller's dense layout (x fastest = OpenVDB's LayoutXYZ) */
        const size_t count = static_cast<size_t>(nx) * static_cast<size_t>(ny) * static_cast<size_t>(nz);
        DR_TRY(dr_calloc(count, sizeof(float), &phi, err));
        const openvdb::Coord cmin(static_cast<int>(ilo[0]), static_cast<int>(ilo[1]),
                                  static_cast<int>(ilo[2]));
        const openvdb::CoordBBox bbox(cmin, cmin.offsetBy(nx - 1, ny - 1, nz - 1));
        openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(bbox, phi);
        openvdb::tools::copyToDense(*grid, dense);

        out->nx = nx;
        out->ny = ny;
        out->nz = nz;
        out->dx = dx;
        out->origin = dr_v3(ilo[0] * dx, ilo[1] * dx, ilo[2] * dx);
        out->phi = phi;
        return DR_OK;
    } catch (...) {
        std::free(phi);
        return translate_exception("converting the collider mesh to a signed distance field", NULL, err);
    }
}

extern "C" void dr_dense_sdf_free(DrDenseSdf *sdf)
{
    if (!sdf) return;
    std::free(sdf->phi);
    std::memset(sdf, 0, sizeof *sdf);
}

extern "C" DrVdbSurfaceDesc dr_vdb_surface_desc_default(void)
{
    DrVdbSurfaceDesc d;
    d.voxel_size = 0.004;
    d.radius = 0.006;
    d.smoothing = 1;
    d.adaptivity = 0.0;
    return d;
}

extern "C" DrStatus dr_vdb_surface_from_particles(const double *pos, const double *vel, long n,
                                                  const DrVdbSurfaceDesc *desc, DrVdbSurface **out,
                                                  DrError *err)
{
    assert(desc && out);
    *out = nullptr;
    DrVdbSurface *s = nullptr;
    try {
        ensure_init();
        DR_TRY(validate_desc(desc, err));
        const double dx = desc->voxel_size;
        DR_TRY(validate_particles(pos, vel, n, dx, err));
        double radius = desc->radius;
        if (radius < kMinRadiusVoxels * dx) {
            dr_log_debug("vdb: particle radius %g m is below %.1f voxels; raised to %g m", radius,
                         kMinRadiusVoxels, kMinRadiusVoxels * dx);
            radius = kMinRadiusVoxels * dx;
        }

        s = new DrVdbSurface();
        s->adaptivity = desc->adaptivity;
        if (n == 0) {
            s->surface = openvdb::createLevelSet<openvdb::FloatGrid>(dx, kSurfaceHalfWidth);
            s->vel = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f, 0.0f, 0.0f));
            s->vel->setTransform(s->surface->transform().copy());
            name_grids(s);
            *out = s;
            return DR_OK;
        }

        /* 1. union of spheres (ParticlesToLevelSet), carrying the closest particle's velocity.
         *    Raster band = kRasterHalfWidth voxels (background = w * dx). */
        openvdb::FloatGrid::Ptr raw =
            openvdb::createLevelSet<openvdb::FloatGrid>(dx, static_cast<float>(kRasterHalfWidth));
        ParticleList particles{pos, vel, static_cast<size_t>(n), radius};
        openvdb::tools::ParticlesToLevelSet<openvdb::FloatGrid, openvdb::Vec3s> raster(*raw);
        /* The radius was clamped above; a lower Rmin only keeps the comparison radius/dx < 1.5
         * from dropping spheres of exactly 1.5 voxels through rounding. */
        raster.setRmin(1.0);
        raster.setRmax(kMaxRadiusVoxels + 1.0);
        raster.rasterizeSpheres(particles, radius);
        raster.finalize(true);
        if (raster.ignoredParticles()) {
            dr_vdb_surface_destroy(&s);
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "OpenVDB ignored %zu particles of radius %g m (voxel %g m)",
                                raster.getMinCount() + raster.getMaxCount(), radius, dx);
        }
        openvdb::Vec3SGrid::Ptr att = raster.attributeGrid();

        /* 2. rasterising leaves the interior active and the band ragged: rebuild a clean narrow
         *    band of kSurfaceHalfWidth voxels around the zero crossing. */
        /*    Spheres smaller than ParticlesToLevelSet resolves were rasterised larger; extracting
         *    the level −(raster radius − requested radius) (phi is negative inside) instead of zero
         *    erodes the union back, so the surface lies the requested radius beyond the outermost
         *    particle centres. */
        s->surface = openvdb::tools::levelSetRebuild(*raw, static_cast<float>(desc->radius - radius),
                                                     kSurfaceHalfWidth);
        raw.reset();
        s->surface->setGridClass(openvdb::GRID_LEVEL_SET);

        /* 3. smoothing: mean-curvature flow; LevelSetFilter renormalises (reinitialises |grad phi|
         *    = 1 and rebuilds the band) after each pass. */
        if (desc->smoothing > 0 && s->surface->activeVoxelCount() > 0) {
            openvdb::tools::LevelSetFilter<openvdb::FloatGrid> filter(*s->surface);
            for (int pass = 0; pass < desc->smoothing; pass++) filter.meanCurvature();
        }

        /* 4. velocity on the final band's topology */
        s->vel = transfer_velocity(*s->surface, *att);
        name_grids(s);
        *out = s;
        return DR_OK;
    } catch (...) {
        delete s;
        return translate_exception("building the liquid surface from particles", NULL, err);
    }
}

extern "C" void dr_vdb_surface_destroy(DrVdbSurface **s)
{
    if (!s || !*s) return;
    delete *s;
    *s = nullptr;
}

extern "C" double dr_vdb_surface_volume(const DrVdbSurface *s)
{
    assert(s);
    try {
        if (s->surface->activeVoxelCount() == 0) return 0.0;
        return openvdb::tools::levelSetVolume(*s->surface, true);
    } catch (const std::exception &e) {
        dr_log_error("vdb: level-set volume failed: %s", e.what());
        return NAN;
    } catch (...) {
        dr_log_error("vdb: level-set volume failed with an unknown exception");
        return NAN;
    }
}

extern "C" double dr_vdb_surface_voxel_size(const DrVdbSurface *s)
{
    assert(s);
    return s->surface->voxelSize()[0];
}

extern "C" long dr_vdb_surface_active_voxels(const DrVdbSurface *s)
{
    assert(s);
    try {
        return static_cast<long>(s->surface->activeVoxelCount());
    } catch (...) {
        dr_log_error("vdb: counting active voxels failed");
        return -1;
    }
}

extern "C" DrVec3 dr_vdb_surface_velocity_at(const DrVdbSurface *s, DrVec3 p)
{
    assert(s);
    try {
        /* "CellCentered" rounds to the nearest voxel centre ("NodeCentered" floors). */
        const openvdb::Coord c =
            s->vel->transform().worldToIndexCellCentered(openvdb::Vec3d(p.x, p.y, p.z));
        const openvdb::Vec3s v = s->vel->getConstAccessor().getValue(c);
        return dr_v3(v[0], v[1], v[2]);
    } catch (...) {
        dr_log_error("vdb: velocity lookup failed");
        return dr_v3(0.0, 0.0, 0.0);
    }
}

extern "C" DrStatus dr_vdb_surface_to_mesh(const DrVdbSurface *s, DrTriMesh *out, DrError *err)
{
    assert(s && out);
    std::memset(out, 0, sizeof *out);
    try {
        if (s->surface->activeVoxelCount() == 0) return DR_OK;

        /* 1. dual contouring of the zero level set */
        std::vector<openvdb::Vec3s> pts;
        std::vector<openvdb::Vec3I> tris;
        std::vector<openvdb::Vec4I> quads;
        openvdb::tools::volumeToMesh(*s->surface, pts, tris, quads, 0.0, s->adaptivity, true);

        /* 2. triangles, reversed: volumeToMesh winds clockwise seen from outside. Quads are split
         *    along the shorter diagonal (better-shaped triangles). */
        std::vector<int> t;
        t.reserve(3 * (tris.size() + 2 * quads.size()));
        if (pts.size() > static_cast<size_t>(INT_MAX) ||
            tris.size() + 2 * quads.size() > static_cast<size_t>(INT_MAX) / 3)
            return dr_error_set(err, DR_ERR_RUNTIME, NULL, 0, 0,
                                "liquid mesh has %zu vertices and %zu polygons, beyond int indices; use "
                                "a larger voxel size or adaptivity",
                                pts.size(), tris.size() + quads.size());
        for (const openvdb::Vec3I &f : tris) {
            t.push_back(static_cast<int>(f[0]));
            t.push_back(static_cast<int>(f[2]));
            t.push_back(static_cast<int>(f[1]));
        }
        for (const openvdb::Vec4I &q : quads) {
            const int a = static_cast<int>(q[0]), b = static_cast<int>(q[3]), c = static_cast<int>(q[2]),
                      d = static_cast<int>(q[1]); /* reversed quad a b c d */
            const float ac = (pts[a] - pts[c]).lengthSqr(), bd = (pts[b] - pts[d]).lengthSqr();
            if (ac <= bd) {
                const int f[6] = {a, b, c, a, c, d};
                t.insert(t.end(), f, f + 6);
            } else {
                const int f[6] = {a, b, d, b, c, d};
                t.insert(t.end(), f, f + 6);
            }
        }

        if (t.empty()) return DR_OK; /* a band without a zero crossing */

        /* 3. keep only used vertices, in their original order */
        std::vector<int> remap(pts.size(), -1);
        for (int idx : t) remap[idx] = 0;
        int nv = 0;
        for (int &r : remap)
            if (r == 0) r = nv++;
        const int nt = static_cast<int>(t.size() / 3);

        DrTriMesh m;
        std::memset(&m, 0, sizeof m);
        if (DR_FAILED(dr_calloc(3 * static_cast<size_t>(nv), sizeof(double), &m.v, err)) ||
            DR_FAILED(dr_calloc(3 * static_cast<size_t>(nv), sizeof(double), &m.n, err)) ||
            DR_FAILED(dr_calloc(3 * static_cast<size_t>(nt), sizeof(int), &m.tri, err))) {
            dr_trimesh_free(&m);
            return DR_ERR_NOMEM;
        }
        m.nv = nv;
        m.nt = nt;
        for (size_t i = 0; i < pts.size(); i++) {
            if (remap[i] < 0) continue;
            for (int a = 0; a < 3; a++) m.v[3 * remap[i] + a] = pts[i][a];
        }
        for (size_t i = 0; i < t.size(); i++) m.tri[i] = remap[t[i]];

        /* 4. normals: area-weighted face normals as the fallback, replaced by the normalised
         *    level-set gradient (central differences of the trilinear interpolant, half a voxel
         *    each way) wherever it is well defined. */
        for (int f = 0; f < nt; f++) {
            const int *ix = m.tri + 3 * f;
            const DrVec3 A = dr_v3(m.v[3 * ix[0]], m.v[3 * ix[0] + 1], m.v[3 * ix[0] + 2]);
            const DrVec3 B = dr_v3(m.v[3 * ix[1]], m.v[3 * ix[1] + 1], m.v[3 * ix[1] + 2]);
            const DrVec3 C = dr_v3(m.v[3 * ix[2]], m.v[3 * ix[2] + 1], m.v[3 * ix[2] + 2]);
            const DrVec3 an = dr_v3_cross(dr_v3_sub(B, A), dr_v3_sub(C, A)); /* 2 * area * normal */
            for (int k = 0; k < 3; k++) {
                m.n[3 * ix[k]] += an.x;
                m.n[3 * ix[k] + 1] += an.y;
                m.n[3 * ix[k] + 2] += an.z;
            }
        }
        const openvdb::math::Transform &xf = s->surface->transform();
        auto acc = s->surface->getConstAccessor();
        for (int i = 0; i < nv; i++) {
            const openvdb::Vec3d ip = xf.worldToIndex(openvdb::Vec3d(m.v[3 * i], m.v[3 * i + 1], m.v[3 * i + 2]));
            double g[3];
            for (int a = 0; a < 3; a++) {
                openvdb::Vec3d e(0.0, 0.0, 0.0);
                e[a] = 0.5;
                g[a] = static_cast<double>(openvdb::tools::BoxSampler::sample(acc, ip + e)) -
                       static_cast<double>(openvdb::tools::BoxSampler::sample(acc, ip - e));
            }
            DrVec3 n = dr_v3(g[0], g[1], g[2]);
            /* |grad phi| ~ 1 in a renormalised band, so a difference over one voxel is ~dx; a much
             * smaller one means the stencil straddles two sheets or the band edge. */
            if (!(dr_v3_norm(n) > 0.25 * xf.voxelSize()[0]))
                n = dr_v3(m.n[3 * i], m.n[3 * i + 1], m.n[3 * i + 2]);
            n = dr_v3_normalize(n);
            m.n[3 * i] = n.x;
            m.n[3 * i + 1] = n.y;
            m.n[3 * i + 2] = n.z;
        }
        *out = m;
        return DR_OK;
    } catch (...) {
        dr_trimesh_free(out);
        return translate_exception("meshing the liquid surface", NULL, err);
    }
}

/* OpenVDB stamps every file with a random UUID (bytes 21..56 of the header: magic, format and library
 * versions, the offsets flag, then 36 characters). A random stamp would make two identical surfaces differ
 * byte for byte, so the stamp is replaced by one derived from the file's content (the hash of the file
 * with the stamp blanked): same content, same bytes; other content, another UUID, which is all OpenVDB's
 * readers use it for. Returns false when the header is not laid out as expected (left untouched). */
static bool stamp_content_uuid(const std::string &path)
{
    const long at = 21, len = 36;
    FILE *f = std::fopen(path.c_str(), "r+b");
    if (!f) return false;
    std::vector<unsigned char> bytes;
    unsigned char buf[65536];
    size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) bytes.insert(bytes.end(), buf, buf + n);
    bool ok = bytes.size() > (size_t)(at + len);
    for (long i = 0; ok && i < len; i++) {
        const unsigned char c = bytes[(size_t)(at + i)];
        ok = (i == 8 || i == 13 || i == 18 || i == 23) ? c == '-' : std::isxdigit(c) != 0;
    }
    if (ok) {
        std::memset(&bytes[(size_t)at], '0', (size_t)len);
        char hex[33], uuid[37];
        dr_hash_hex(dr_hash_bytes(bytes.data(), bytes.size()), hex);
        std::snprintf(uuid, sizeof uuid, "%.8s-%.4s-%.4s-%.4s-%.12s", hex, hex + 8, hex + 12, hex + 16, hex + 20);
        ok = std::fseek(f, at, SEEK_SET) == 0 && std::fwrite(uuid, 1, (size_t)len, f) == (size_t)len;
    }
    ok = (std::fclose(f) == 0) && ok;
    return ok;
}

extern "C" DrStatus dr_vdb_surface_write(const DrVdbSurface *s, const char *path, const DrVdbMeta *meta,
                                         DrError *err)
{
    assert(s && path && meta);
    std::string tmp;
    try {
        ensure_init();
        tmp = std::string(path) + ".tmp." + std::to_string(static_cast<long>(getpid()));
        openvdb::GridCPtrVec grids;
        grids.push_back(s->surface);
        grids.push_back(s->vel);
        openvdb::MetaMap info;
        info.insertMeta("creator", openvdb::StringMetadata("drench " DR_VERSION));
        info.insertMeta("frame", openvdb::Int32Metadata(meta->frame));
        info.insertMeta("fps", openvdb::DoubleMetadata(meta->fps));
        info.insertMeta("units", openvdb::StringMetadata("m"));
        info.insertMeta("up_axis", openvdb::StringMetadata("y"));
        info.insertMeta("bake_key", openvdb::StringMetadata(meta->bake_key ? meta->bake_key : ""));
        {
            openvdb::io::File file(tmp);
            file.write(grids, info);
        }
        if (!stamp_content_uuid(tmp)) {
            std::remove(tmp.c_str());
            return dr_error_set(err, DR_ERR_IO, path, 0, 0,
                                "writing %s: could not rewrite the file's UUID stamp (unexpected OpenVDB header "
                                "or a write error); check free disk space",
                                path);
        }
        /* Read the descriptors back before the rename: a short write (disk full) fails here,
         * not in a later stage that trusts the file. */
        {
            openvdb::io::File check(tmp);
            check.open(false);
            size_t count = 0;
            for (auto it = check.beginName(); it != check.endName(); ++it) count++;
            check.close();
            if (count != 2) {
                std::remove(tmp.c_str());
                return dr_error_set(err, DR_ERR_IO, path, 0, 0,
                                    "writing %s: the written file holds %zu grids instead of 2; "
                                    "check free disk space",
                                    path, count);
            }
        }
        if (std::rename(tmp.c_str(), path) != 0) {
            const int e = errno;
            std::remove(tmp.c_str());
            return dr_error_set(err, DR_ERR_IO, path, 0, 0, "could not rename %s onto %s: %s",
                                tmp.c_str(), path, std::strerror(e));
        }
        return DR_OK;
    } catch (...) {
        if (!tmp.empty()) std::remove(tmp.c_str());
        return translate_exception("writing the liquid .vdb", path, err);
    }
}

extern "C" DrStatus dr_vdb_file_info(const char *path, char *grid_names, size_t size, DrError *err)
{
    assert(path && grid_names);
    try {
        ensure_init();
        openvdb::io::File file(path);
        file.open(false);
        std::string names;
        for (auto it = file.beginName(); it != file.endName(); ++it) {
            if (!names.empty()) names += ",";
            names += it.gridName();
        }
        file.close();
        return copy_out(names, grid_names, size, "the grid name list", err);
    } catch (...) {
        return translate_exception("reading the .vdb", path, err);
    }
}

extern "C" DrStatus dr_vdb_file_meta(const char *path, const char *key, char *value, size_t size,
                                     DrError *err)
{
    assert(path && key && value);
    try {
        ensure_init();
        openvdb::io::File file(path);
        file.open(false);
        openvdb::MetaMap::Ptr info = file.getMetadata();
        file.close();
        openvdb::Metadata::Ptr item = info ? (*info)[key] : openvdb::Metadata::Ptr();
        if (!item)
            return dr_error_set(err, DR_ERR_INPUT, path, 0, 0, "%s has no file metadata item \"%s\"",
                                path, key);
        return copy_out(item->str(), value, size, "the metadata value", err);
    } catch (...) {
        return translate_exception("reading the .vdb metadata", path, err);
    }
}

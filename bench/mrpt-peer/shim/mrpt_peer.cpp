// A C ABI around MRPT's COccupancyGridMap2D for sonar-mrpt-peer: create a grid, insert one
// CObservationRange (a sonar reading) at a pose, read cell probabilities. No C++ exception
// crosses the ABI: each entry point catches and reports it.
#include <mrpt/maps/COccupancyGridMap2D.h>
#include <mrpt/obs/CObservationRange.h>
#include <mrpt/poses/CPose3D.h>

#include <cmath>
#include <cstddef>
#include <cstring>
#include <exception>
#include <new>

namespace
{
void report(const char* what, char* err, size_t err_len)
{
	if (err == nullptr || err_len == 0) return;
	std::strncpy(err, what, err_len - 1);
	err[err_len - 1] = '\0';
}
}  // namespace

// One grid and the observation reused for every reading (one measurement).
struct MrptPeerGrid
{
	mrpt::maps::COccupancyGridMap2D grid;
	mrpt::obs::CObservationRange obs;
};

extern "C" {

MrptPeerGrid* mrpt_peer_grid_new(
	float x_min, float x_max, float y_min, float y_max, float resolution,
	float max_range_m, float aperture_rad, char* err, size_t err_len)
{
	try
	{
		auto* g = new MrptPeerGrid();
		g->grid.setSize(x_min, x_max, y_min, y_max, resolution, 0.5f);
		// Our sensor's reach; a reading at or beyond it (no echo) inserts nothing, as the
		// recommended preset ignores readings without an echo.
		g->grid.insertionOptions.maxDistanceInsertion = max_range_m;
		g->grid.insertionOptions.considerInvalidRangesAsFreeSpace = false;
		g->obs.minSensorDistance = 0.0f;
		g->obs.maxSensorDistance = max_range_m;
		g->obs.sensorConeApperture = aperture_rad;
		g->obs.sensedData.resize(1);
		return g;
	}
	catch (const std::exception& e)
	{
		report(e.what(), err, err_len);
	}
	catch (...)
	{
		report("unknown C++ exception", err, err_len);
	}
	return nullptr;
}

void mrpt_peer_grid_free(MrptPeerGrid* g) { delete g; }

// Inserts one range reading taken at (x, y) with the cone's yaw `yaw_rad` as MRPT takes it
// (the caller centres the cone). Returns 1 if MRPT inserted it, 0 if not, -1 on an exception.
int mrpt_peer_grid_insert(
	MrptPeerGrid* g, double x, double y, double yaw_rad, float range_m)
{
	try
	{
		g->obs.sensedData.front().sensedDistance = range_m;
		const mrpt::poses::CPose3D pose(x, y, 0.0, yaw_rad, 0.0, 0.0);
		return g->grid.insertObservation(g->obs, pose) ? 1 : 0;
	}
	catch (...)
	{
		return -1;
	}
}

// Every cell back to the prior (0.5), the grid's size and caches kept.
void mrpt_peer_grid_clear(MrptPeerGrid* g) { g->grid.fill(0.5f); }

unsigned mrpt_peer_grid_size_x(const MrptPeerGrid* g) { return g->grid.getSizeX(); }
unsigned mrpt_peer_grid_size_y(const MrptPeerGrid* g) { return g->grid.getSizeY(); }

// The occupancy probability of the cells containing the centres of an n × n grid of `resolution`
// cells whose lowest corner is (x0, y0), row-major from the lowest y, into out[n * n]; 0.5
// outside MRPT's grid. MRPT's cell value is the probability of the cell being FREE (its
// isStaticCell calls a cell occupied when getCell <= threshold), hence 1 - getPos.
void mrpt_peer_grid_read(
	const MrptPeerGrid* g, float x0, float y0, float resolution, size_t n, float* out)
{
	for (size_t row = 0; row < n; ++row)
	{
		const float y = y0 + (static_cast<float>(row) + 0.5f) * resolution;
		for (size_t col = 0; col < n; ++col)
		{
			const float x = x0 + (static_cast<float>(col) + 0.5f) * resolution;
			out[row * n + col] = 1.0f - g->grid.getPos(x, y);
		}
	}
}
}

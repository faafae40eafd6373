// cityforge segment: watershed over-segmentation and multi-scale region merging.
#include <cstdio>
#include <memory>
#include <optional>

#include "commands/commands.hpp"
#include "pipeline/segment_raster.hpp"

namespace cityforge::cli {

void add_segment_command(CLI::App& parent, const GlobalFlags& g, CommandList& out) {
    struct State {
        std::string in, out, config, strategy;
        SegmentOptions seg;
        std::vector<double> scales, band_weights;
        std::optional<double> color, compact, h, sigma, gsd;
    };
    auto s = std::make_shared<State>();
    auto* cmd = parent.add_subcommand("segment", "Watershed over-segmentation and multi-scale region merging");
    cmd->add_option("--ortho", s->in, "Input raster (any GDAL format, georeferenced)")->required();
    cmd->add_option("--out", s->out, "Output folder")->required();
    cmd->add_option("--config", s->config, "JSON config (schemas/segment_config.schema.json); options given here override it");
    cmd->add_option("--scales", s->scales, "Increasing scale parameters; merge while cost < scale^2")->delimiter(',');
    cmd->add_option("--strategy", s->strategy, "Queue strategy: rag, nng or mutual (default mutual)")
        ->check(CLI::IsMember({"rag", "nng", "mutual"}));
    cmd->add_option("--color-weight", s->color, "Weight of colour vs shape heterogeneity, 0..1 (default 0.9)");
    cmd->add_option("--compactness", s->compact, "Weight of compactness vs smoothness in the shape term, 0..1 (default 0.5)");
    cmd->add_option("--band-weights", s->band_weights, "One weight per band, for the gradient and the colour term")->delimiter(',');
    cmd->add_option("--h-minima", s->h, "Watershed dynamics threshold, grey levels of the 0..255-normalised image (default 4)");
    cmd->add_option("--smoothing", s->sigma, "Gaussian smoothing before the gradient, sigma in pixels (default 1)");
    cmd->add_option("--gsd", s->gsd, "Working GSD in metres (default 0.5; 0 = keep the input's)");
    cmd->add_flag("--allow-pixel-coordinates", s->seg.allow_pixel_coordinates, "Accept a raster without georeferencing");
    out.push_back({cmd, [s, &g]() {
                       SegmentOptions seg = s->seg;
                       if (!s->config.empty()) {
                           seg = segment_options_from_json(read_json_file(s->config), s->config);
                           seg.allow_pixel_coordinates = s->seg.allow_pixel_coordinates;
                       }
                       if (!s->scales.empty()) seg.merging.scales = s->scales;
                       if (!s->strategy.empty()) seg.merging.strategy = queue_strategy_from_string(s->strategy);
                       if (s->color) seg.merging.color_weight = *s->color;
                       if (s->compact) seg.merging.compactness = *s->compact;
                       if (!s->band_weights.empty()) seg.merging.band_weights = seg.watershed.band_weights = s->band_weights;
                       if (s->h) seg.watershed.h_minima = *s->h;
                       if (s->sigma) seg.watershed.smoothing_sigma_px = *s->sigma;
                       if (s->gsd) seg.working_gsd_m = *s->gsd;
                       const SegmentReport r = segment_raster(s->in, s->out, seg, make_progress(g));
                       if (!g.quiet) {
                           std::fprintf(stderr, "cityforge: watershed %u regions in %.2f s (%d x %d px at %.3g m)\n",
                                        r.oversegmentation_regions, r.watershed_seconds, r.working_width, r.working_height,
                                        r.working_gsd_m);
                           for (const auto& l : r.levels)
                               std::fprintf(stderr, "cityforge: scale %g (%s): %u -> %u regions, queue %llu, %.3f s\n", l.scale,
                                            r.strategy.c_str(), l.regions_before, l.regions_after,
                                            static_cast<unsigned long long>(l.initial_queue_length), l.seconds);
                       }
                       return 0;
                   }});
}

}  // namespace cityforge::cli
